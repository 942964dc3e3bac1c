"""The grid world's fixed layout: cells, moves, obstacles, ROI, starts and targets.

Cells are 1-based (x, y) as in the seed; inside the kernels a cell is the integer index
s = (y − 1)·M + (x − 1). Actions: 0 up (y+1), 1 down (y−1), 2 left (x−1), 3 right (x+1).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from skyherd.policy.sql.params import GridParams

ACTIONS = ("up", "down", "left", "right")
ACTION_DXY = ((0, 1), (0, -1), (-1, 0), (1, 0))

# Built-in formations (1-based (x, y)). K = 9 and 16 follow the seed; K = 4 is ours:
# starts at the seed's commented 4-agent cells, targets on the {48, 50}² lattice. Other
# square K (25, 36, ...) extend the seed's pattern: see `formation`.
STARTS: dict[int, tuple[tuple[int, int], ...]] = {
    4: ((1, 5), (1, 2), (2, 1), (5, 1)),
    9: ((1, 9), (1, 7), (1, 5), (1, 3), (1, 1), (3, 1), (5, 1), (7, 1), (9, 1)),
    16: tuple((1, y) for y in range(16, 0, -2)) + tuple((x, 1) for x in range(16, 0, -2)),
}
TARGET_LATTICE: dict[int, tuple[int, ...]] = {4: (48, 50), 9: (46, 48, 50), 16: (44, 46, 48, 50)}
ROI_MIN: dict[int, int] = {4: 45, 9: 45, 16: 43}


def formation(K: int, size: int = 50):
    """Start cells, target cells (id order) and ROI corner of the K-agent formation.

    K in STARTS: the tables above (targets listed row by row from the top, as the seed's
    `flag_position`). Any other square K = n² ≥ 4: starts every second cell up the left column
    and along the bottom row (odd K: the corner (1, 1) too, as the seed's K = 9; even K: as its
    K = 16), targets on the lattice {M − 2(n − 1), …, M − 2, M}², ROI from one cell below it.
    """
    n = int(round(K**0.5))
    if K < 1 or n * n != K:
        raise ValueError(f"K must be a square number (4, 9, 16, 25, 36, ...), got {K}")
    if K in STARTS and size == 50:
        starts, lattice, roi = STARTS[K], TARGET_LATTICE[K], ROI_MIN[K]
    else:
        lattice = tuple(range(size - 2 * (n - 1), size + 1, 2))
        roi = lattice[0] - 1
        if K % 2:
            h = (K - 1) // 2
            starts = (*((1, 2 * j + 1) for j in range(h, 0, -1)), (1, 1))
            starts += tuple((2 * j + 1, 1) for j in range(1, h + 1))
        else:
            starts = tuple((1, 2 * j) for j in range(K // 2, 0, -1))
            starts += tuple((2 * j, 1) for j in range(K // 2, 0, -1))
        if roi < 2 or max(max(c) for c in starts) >= roi:
            raise ValueError(f"K={K} does not fit a {size}×{size} grid")
    targets = tuple((x, y) for y in reversed(lattice) for x in lattice)
    return tuple(starts), targets, roi


@dataclass(frozen=True, eq=False)
class Layout:
    """Arrays the kernels read. S = M² cells, K agents, T = K targets, R ROI cells."""

    size: int
    """M."""
    next_cell: np.ndarray
    """(S, 4) int32: cell reached by each action, −1 when it would leave the grid."""
    obstacle: np.ndarray
    """(S,) bool: obstacle cells."""
    target_id: np.ndarray
    """(S,) int32: index of the target on a cell, −1 if none."""
    targets: np.ndarray
    """(T,) int32: target cells."""
    roi_id: np.ndarray
    """(S,) int32: index of a cell inside the ROI (0..R−1), −1 outside."""
    starts: np.ndarray
    """(K,) int32: start cells, agent order."""

    @property
    def n_agents(self) -> int:
        return int(self.starts.shape[0])

    @property
    def n_cells(self) -> int:
        return self.size * self.size

    @property
    def n_roi(self) -> int:
        return int((self.roi_id >= 0).sum())

    def cell(self, x: int, y: int) -> int:
        """1-based (x, y) → cell index."""
        if not (1 <= x <= self.size and 1 <= y <= self.size):
            raise ValueError(f"cell ({x}, {y}) is off the {self.size}×{self.size} grid")
        return (y - 1) * self.size + (x - 1)

    def xy(self, s: int) -> tuple[int, int]:
        """Cell index → 1-based (x, y)."""
        return int(s) % self.size + 1, int(s) // self.size + 1


def move_table(size: int) -> np.ndarray:
    """(M², 4) int32 table of the cell each action leads to (−1 off the grid)."""
    nxt = np.full((size * size, 4), -1, dtype=np.int32)
    for y in range(1, size + 1):
        for x in range(1, size + 1):
            s = (y - 1) * size + (x - 1)
            for a, (dx, dy) in enumerate(ACTION_DXY):
                x2, y2 = x + dx, y + dy
                if 1 <= x2 <= size and 1 <= y2 <= size:
                    nxt[s, a] = (y2 - 1) * size + (x2 - 1)
    return nxt


def make_layout(
    size: int,
    starts_xy: list[tuple[int, int]] | tuple[tuple[int, int], ...],
    targets_xy: list[tuple[int, int]] | tuple[tuple[int, int], ...],
    roi_min: int,
    obstacles_xy: list[tuple[int, int]] | tuple[tuple[int, int], ...] = (),
) -> Layout:
    """A layout from explicit cells (used by the tests' tiny worlds and by `build_layout`)."""
    if len(starts_xy) == 0 or len(set(starts_xy)) != len(starts_xy):
        raise ValueError("need at least one start cell, all different")
    S = size * size
    idx = lambda x, y: (y - 1) * size + (x - 1)  # noqa: E731
    for x, y in (*starts_xy, *targets_xy, *obstacles_xy):
        if not (1 <= x <= size and 1 <= y <= size):
            raise ValueError(f"cell ({x}, {y}) is off the {size}×{size} grid")
    roi_id = np.full(S, -1, dtype=np.int32)
    k = 0
    for y in range(roi_min, size + 1):
        for x in range(roi_min, size + 1):
            roi_id[idx(x, y)] = k
            k += 1
    obstacle = np.zeros(S, dtype=np.bool_)
    for x, y in obstacles_xy:
        obstacle[idx(x, y)] = True
    target_id = np.full(S, -1, dtype=np.int32)
    targets = np.array([idx(x, y) for x, y in targets_xy], dtype=np.int32)
    target_id[targets] = np.arange(len(targets), dtype=np.int32)
    starts = np.array([idx(x, y) for x, y in starts_xy], dtype=np.int32)
    if obstacle[starts].any() or obstacle[targets].any():
        raise ValueError("an obstacle sits on a start or target cell")
    return Layout(size, move_table(size), obstacle, target_id, targets, roi_id, starts)


def _reachable(layout: Layout) -> np.ndarray:
    """(S,) bool: cells reachable from the first start cell around obstacles (BFS)."""
    seen = np.zeros(layout.n_cells, dtype=np.bool_)
    q = deque([int(layout.starts[0])])
    seen[layout.starts[0]] = True
    while q:
        s = q.popleft()
        for s2 in layout.next_cell[s]:
            if s2 >= 0 and not seen[s2] and not layout.obstacle[s2]:
                seen[s2] = True
                q.append(int(s2))
    return seen


def build_layout(grid: GridParams) -> Layout:
    """The seed's world for K ∈ {4, 9, 16} (and other square K, `formation`): obstacles drawn
    by `grid.map_seed`.

    Obstacles: round(fraction·M²) distinct cells, uniformly drawn outside the ROI and the start
    cells. A draw that walls off a start cell or the ROI is redrawn (next draw of the same
    generator), so every map is solvable.
    """
    K, M = grid.n_agents, grid.size
    if M < 50:
        raise ValueError(f"the built-in layouts need a grid of at least 50 cells, got {M}")
    starts_xy, targets_xy, roi_min = formation(K, 50)
    base = make_layout(M, starts_xy, targets_xy, roi_min)
    n_obst = int(round(grid.obstacle_fraction * M * M))
    free = np.flatnonzero(base.roi_id < 0)
    free = np.setdiff1d(free, base.starts)
    rng = np.random.default_rng(grid.map_seed)
    for _ in range(100):
        cells = rng.choice(free, size=n_obst, replace=False)
        obstacle = np.zeros(M * M, dtype=np.bool_)
        obstacle[cells] = True
        lay = Layout(
            M, base.next_cell, obstacle, base.target_id, base.targets, base.roi_id, base.starts
        )
        seen = _reachable(lay)
        if seen[lay.starts].all() and seen[lay.roi_id >= 0].all():
            return lay
    raise ValueError(f"no solvable obstacle map found for map_seed={grid.map_seed}")
