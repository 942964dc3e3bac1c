"""Grid-world maps as data: generated like the seed study's maps, or read from / written to JSON.

JSON format (cells 1-based [x, y], x to the right, y up):

    {"size": 50, "roi_area": 45,
     "obstacles": [[x, y], ...],   # duplicates allowed (the study's generator draws with
                                   # replacement, so a map may hold fewer distinct cells)
     "starts": [[x, y], ...],      # one per agent, agent order
     "flags":  [[x, y], ...]}      # one per agent, target id order

The ROI is every cell with x ≥ roi_area and y ≥ roi_area (the published `ROI_area`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyherd.policy.sql.layout import Layout, _reachable, formation, make_layout

Cell = tuple[int, int]


@dataclass(frozen=True)
class EnvSpec:
    """One map, as listed in its JSON file."""

    size: int
    roi_area: int
    obstacles: tuple[Cell, ...]
    starts: tuple[Cell, ...]
    flags: tuple[Cell, ...]

    def __post_init__(self) -> None:
        if self.size < 2 or not 1 <= self.roi_area <= self.size:
            raise ValueError(
                f"need size >= 2 and 1 <= roi_area <= size, got {self.size}, {self.roi_area}"
            )
        if len(self.starts) != len(self.flags) or not self.starts:
            raise ValueError(
                f"need as many flags as starts (>= 1): {len(self.starts)} vs {len(self.flags)}"
            )
        if len(set(self.flags)) != len(self.flags):
            raise ValueError("flags must be different cells")
        roi = lambda c: c[0] >= self.roi_area and c[1] >= self.roi_area  # noqa: E731
        if not all(roi(c) for c in self.flags):
            raise ValueError("every flag must lie in the ROI (x, y >= roi_area)")
        if any(roi(c) for c in self.starts):
            raise ValueError("a start cell lies in the ROI")

    def layout(self) -> Layout:
        """The kernels' arrays (raises ValueError on off-grid cells or blocked starts)."""
        return make_layout(self.size, self.starts, self.flags, self.roi_area, self.obstacles)

    def to_json(self) -> str:
        d = {
            "size": self.size,
            "roi_area": self.roi_area,
            "obstacles": [list(c) for c in self.obstacles],
            "starts": [list(c) for c in self.starts],
            "flags": [list(c) for c in self.flags],
        }
        return json.dumps(d, indent=None, separators=(",", ":")) + "\n"

    @staticmethod
    def from_json(text: str) -> EnvSpec:
        """Parse a map; a missing key or a bad value is a ValueError naming it."""
        try:
            d = json.loads(text)
        except json.JSONDecodeError as e:
            raise ValueError(f"not JSON: {e}") from None
        if not isinstance(d, dict):
            raise ValueError("the map must be a JSON object")
        missing = {"size", "roi_area", "obstacles", "starts", "flags"} - set(d)
        if missing:
            raise ValueError(f"map is missing {sorted(missing)}")

        def cells(key: str) -> tuple[Cell, ...]:
            v = d[key]
            ok = isinstance(v, list) and all(
                isinstance(c, list) and len(c) == 2 and all(isinstance(u, int) for u in c)
                for c in v
            )
            if not ok:
                raise ValueError(f'"{key}" must be a list of [x, y] integer pairs')
            return tuple((int(x), int(y)) for x, y in v)

        if not (isinstance(d["size"], int) and isinstance(d["roi_area"], int)):
            raise ValueError('"size" and "roi_area" must be integers')
        return EnvSpec(
            d["size"], d["roi_area"], cells("obstacles"), cells("starts"), cells("flags")
        )

    @staticmethod
    def load(path: str | Path) -> EnvSpec:
        return EnvSpec.from_json(Path(path).read_text())


def generate_env(n_agents: int, seed: int, size: int = 50, density: float = 0.02) -> EnvSpec:
    """A map as the study's `create_environment.m` makes it, for the K-agent formation.

    round(density · size²) obstacle draws, each a uniform cell outside the ROI and the start
    cells, drawn with replacement (duplicates allowed, as there). Ours in addition: a map that
    walls off a start cell or the ROI is redrawn (the next draws of the same generator), so
    every map is solvable.
    """
    starts, flags, roi = formation(n_agents, size)
    if not 0.0 <= density < 0.5:
        raise ValueError(f"density must be in [0, 0.5), got {density}")
    rng = np.random.default_rng(int(seed))
    n = int(round(density * size * size))
    start_set = set(starts)
    for _ in range(100):
        obst: list[Cell] = []
        while len(obst) < n:
            x, y = (int(v) for v in rng.integers(1, size + 1, size=2))
            if (x >= roi and y >= roi) or (x, y) in start_set:
                continue
            obst.append((x, y))
        spec = EnvSpec(size, roi, tuple(obst), starts, flags)
        lay = spec.layout()
        seen = _reachable(lay)
        if seen[lay.starts].all() and seen[lay.roi_id >= 0].all():
            return spec
    raise ValueError(f"no solvable map found for K={n_agents}, seed={seed}")


def load_env_file(path: str | Path) -> EnvSpec:
    """The map file of `--env` (`skyherd train sql`, `skyherd reproduce sql`), its layout
    checked; ValueError naming --env."""
    try:
        spec = EnvSpec.load(path)
        spec.layout()
    except (OSError, ValueError) as e:
        raise ValueError(f"--env {path}: {e}") from None
    return spec
