"""What a UGV is: its state, its drive limits and its look (body and top marker).

Shared by the kinematic world, the PyBullet world and both renderers, so that a marker is the
same size and colour everywhere. Positions are north/east on the ground [m] (NED, down = 0),
headings from north, clockwise [rad].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# Saturated marker colours (RGB 0..255): the detector keys on saturation, the ground is dull.
MARKER_COLOURS: tuple[tuple[int, int, int], ...] = (
    (230, 30, 30),  # red
    (30, 80, 230),  # blue
    (240, 200, 20),  # yellow
    (230, 30, 220),  # magenta
    (20, 200, 220),  # cyan
    (250, 120, 10),  # orange
)
GROUND_RGB: tuple[int, int, int] = (118, 124, 108)  # dull olive-grey field
BODY_RGB: tuple[int, int, int] = (60, 60, 62)  # dark grey hull


@dataclass(frozen=True)
class UGVModel:
    """Geometry and look of a box-shaped UGV (sizes [m]).

    The top marker is a square plate on the roof; its centre is the point the detector finds
    and the point `marker_points_ned` projects. The hull is dark and unsaturated so that only
    the marker shows as a saturated blob, whatever the camera's attitude.
    """

    length_m: float = 1.0
    width_m: float = 0.7
    height_m: float = 0.4
    marker_size_m: float = 1.0  # side of the square top marker [m]
    marker_thickness_m: float = 0.02
    mass_kg: float = 50.0

    @property
    def marker_top_m(self) -> float:
        """Height of the marker's top face above the ground [m]."""
        return self.height_m + self.marker_thickness_m


@dataclass(frozen=True)
class UGVStates:
    """State of N UGVs at one instant.

    pos_ne     (N, 2) north, east [m] (centre of the hull on the ground)
    heading    (N,) from north, clockwise [rad]
    speed      (N,) forward speed [m/s]
    camouflaged (N,) bool: the marker has taken the ground's colour
    """

    pos_ne: np.ndarray
    heading: np.ndarray
    speed: np.ndarray
    camouflaged: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        if self.camouflaged is None:
            object.__setattr__(self, "camouflaged", np.zeros(len(self.heading), dtype=bool))

    @property
    def n(self) -> int:
        return int(self.heading.shape[0])


def marker_points_ned(states: UGVStates, model: UGVModel) -> np.ndarray:
    """Centres of the top markers' upper faces, (N, 3) NED [m]."""
    n = states.n
    out = np.empty((n, 3))
    out[:, :2] = states.pos_ne
    out[:, 2] = -model.marker_top_m
    return out


# a square's corners in order around it, as (forward, right) signs
_SQUARE_FWD, _SQUARE_RIGHT = np.array([1.0, 1.0, -1.0, -1.0]), np.array([1.0, -1.0, -1.0, 1.0])


def corners_ned(states: UGVStates, model: UGVModel) -> np.ndarray:
    """(N, 12, 3) NED corners [m] of each UGV: its hull box's 8 (the ground square's 4, then the
    top's), then its top marker's 4, each square in order around it. One pass for the team: the
    fast renderer projects these at every camera frame."""
    c, s = np.cos(states.heading)[:, None], np.sin(states.heading)[:, None]  # (N, 1)
    n, e = states.pos_ne[:, 0:1], states.pos_ne[:, 1:2]
    f, r = _SQUARE_FWD, _SQUARE_RIGHT
    # a corner: the centre + its offsets along the heading (cos, sin) and to the right (−sin, cos)
    out = np.empty((states.n, 12, 3))
    a, b = 0.5 * model.length_m * f, 0.5 * model.width_m * r
    out[:, :4, 0], out[:, :4, 1] = n + (a * c - b * s), e + (a * s + b * c)
    out[:, 4:8, :2] = out[:, :4, :2]
    out[:, :4, 2], out[:, 4:8, 2] = 0.0, -model.height_m
    h = 0.5 * model.marker_size_m
    out[:, 8:, 0], out[:, 8:, 1] = n + h * (f * c - r * s), e + h * (f * s + r * c)
    out[:, 8:, 2] = -model.marker_top_m
    return out


def marker_corners_ned(states: UGVStates, model: UGVModel) -> np.ndarray:
    """Corners of each top marker, (N, 4, 3) NED [m], in order around the square."""
    return corners_ned(states, model)[:, 8:]


def initial_states(pos_ne: np.ndarray, heading: np.ndarray | None = None) -> UGVStates:
    """UGVs at rest at `pos_ne` (N, 2) [m], headings (N,) [rad] (default north)."""
    pos = np.asarray(pos_ne, dtype=float).reshape(-1, 2).copy()
    n = pos.shape[0]
    hd = np.zeros(n) if heading is None else np.asarray(heading, dtype=float).copy()
    return UGVStates(pos, hd, np.zeros(n))
