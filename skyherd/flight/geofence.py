"""The vehicle's own geofence: what the built-in autopilots enforce (PX4 semantics).

Sources, combined (a point must satisfy every active one):
  * the fence uploaded over MAVLink (mission_type FENCE), handed over as shapes with the
    attributes of `flight.mavlink.mission.FenceShape` (kind "polygon" | "circle" | "return",
    inclusion, vertices_ne (k, 2), center_ne (2,), radius [m]). As in PX4's navigator
    (Geofence::checkPolygons) the inclusion areas are a union (inside at least one, when
    there is any) and every exclusion area must be avoided;
  * the parameter cylinder about home: GF_MAX_HOR_DIST [m] horizontal radius and
    GF_MAX_VER_DIST [m] height above home (0 = that limit off), as PX4.

Breach (`FenceMonitor`): GF_COUNT consecutive position samples outside (sampled at
`SAMPLE_HZ`) trigger the action GF_ACTION once: 0 none, 1 warning, 2 hold / loiter,
3 return (RTL), 4 terminate (not simulated: lands), 5 land. Back inside re-arms the monitor.
Targets (reposition, offboard positions, mission items, takeoff height) outside are refused
by the autopilot before they are flown. All positions NED about home [m].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from skyherd.flight.params import ParamSpec

SAMPLE_HZ = 20.0  # [Hz] breach checks per second of simulated time
ACTION_NONE, ACTION_WARN, ACTION_HOLD, ACTION_RTL, ACTION_TERMINATE, ACTION_LAND = range(6)
ACTION_NAMES = {0: "none", 1: "warning", 2: "hold", 3: "return", 4: "land (terminate)", 5: "land"}

GEOFENCE_PARAMS: tuple[ParamSpec, ...] = (
    ParamSpec("GF_ACTION", 2.0, 0.0, 5.0, "on breach: 0 none 1 warn 2 hold 3 RTL 4/5 land", "-"),
    ParamSpec("GF_MAX_HOR_DIST", 0.0, 0.0, 100000.0, "horizontal limit from home, 0 = off", "m"),
    ParamSpec("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0, "height limit above home, 0 = off", "m"),
    ParamSpec("GF_COUNT", 1.0, 1.0, 20.0, "consecutive samples outside before a breach", "-"),
)


def _in_polygon(n: float, e: float, verts: np.ndarray) -> bool:
    """Even-odd ray cast (north ray) for a simple polygon (k, 2) of (north, east) vertices."""
    inside = False
    k = len(verts)
    j = k - 1
    for i in range(k):
        ni, ei = verts[i]
        nj, ej = verts[j]
        if (ei > e) != (ej > e):
            n_cross = ni + (e - ei) * (nj - ni) / (ej - ei)
            if n < n_cross:
                inside = not inside
        j = i
    return inside


@dataclass(frozen=True)
class _Area:
    inclusion: bool
    kind: str  # "polygon" | "circle"
    verts: np.ndarray | None = None
    center: tuple[float, float] = (0.0, 0.0)
    radius: float = 0.0

    def contains(self, n: float, e: float) -> bool:
        if self.kind == "circle":
            return math.hypot(n - self.center[0], e - self.center[1]) <= self.radius
        return _in_polygon(n, e, self.verts)


class Geofence:
    """Uploaded areas plus the parameter cylinder. `violation(pos)` → reason or None."""

    def __init__(self, shapes: Sequence = (), max_hor: float = 0.0, max_ver: float = 0.0):
        areas: list[_Area] = []
        for s in shapes or ():
            kind = getattr(s, "kind", None)
            if kind == "circle":
                c = np.asarray(s.center_ne, dtype=float).reshape(2)
                areas.append(
                    _Area(bool(s.inclusion), "circle", None, (c[0], c[1]), float(s.radius))
                )
            elif kind == "polygon":
                v = np.asarray(s.vertices_ne, dtype=float).reshape(-1, 2)
                areas.append(_Area(bool(s.inclusion), "polygon", v))
            # "return" points carry no area
        self.areas = tuple(areas)
        self._incl = tuple(a for a in areas if a.inclusion)
        self._excl = tuple(a for a in areas if not a.inclusion)
        self.max_hor = float(max_hor)
        self.max_ver = float(max_ver)

    @property
    def active(self) -> bool:
        return bool(self.areas) or self.max_hor > 0.0 or self.max_ver > 0.0

    def violation(self, pos_ned) -> str | None:
        """Why `pos_ned` (3,) [m] is outside, or None when it is allowed."""
        n, e, d = float(pos_ned[0]), float(pos_ned[1]), float(pos_ned[2])
        if self.max_hor > 0.0 and math.hypot(n, e) > self.max_hor:
            return f"{math.hypot(n, e):.0f} m from home > GF_MAX_HOR_DIST {self.max_hor:g}"
        if self.max_ver > 0.0 and -d > self.max_ver:
            return f"height {-d:.0f} m > GF_MAX_VER_DIST {self.max_ver:g}"
        if self._incl and not any(a.contains(n, e) for a in self._incl):
            return "outside the inclusion fence"
        for a in self._excl:
            if a.contains(n, e):
                return "inside an exclusion zone"
        return None

    def contains(self, pos_ned) -> bool:
        return self.violation(pos_ned) is None

    def circle_violation(
        self, center_ne, radius: float, down: float, n_pts: int = 12
    ) -> str | None:
        """A loiter circle (fixed-wing): its centre and `n_pts` points on it must be inside."""
        c = np.asarray(center_ne, dtype=float)
        why = self.violation((c[0], c[1], down))
        if why is not None or radius <= 0.0:
            return why
        for k in range(n_pts):
            a = 2.0 * math.pi * k / n_pts
            why = self.violation((c[0] + radius * math.cos(a), c[1] + radius * math.sin(a), down))
            if why is not None:
                return f"loiter circle r {radius:.0f} m: {why}"
        return None


class FenceMonitor:
    """Breach detector: `sample(t, pos)` → the action to take now (or None), once per breach."""

    def __init__(self) -> None:
        self.fence = Geofence()
        self.shapes: tuple = ()
        self.outside_count = 0
        self.breached = False  # latched until back inside
        self.last_reason = ""
        self.breaches = 0
        self._next_t = 0.0

    def configure(self, shapes: Sequence | None, max_hor: float, max_ver: float) -> None:
        """New uploaded shapes (None keeps the present ones) and the cylinder limits [m]."""
        if shapes is not None:
            self.shapes = tuple(shapes)
        self.fence = Geofence(self.shapes, max_hor, max_ver)

    def due(self, t: float) -> bool:
        """True at most SAMPLE_HZ times per simulated second (cheap test for the hot loop)."""
        if t + 1e-9 < self._next_t:
            return False
        self._next_t = t + 1.0 / SAMPLE_HZ
        return True

    def sample(self, pos_ned, count_needed: int) -> str | None:
        """One position sample; the breach reason when this sample completes a breach."""
        why = self.fence.violation(pos_ned)
        if why is None:
            self.outside_count = 0
            self.breached = False
            return None
        self.outside_count += 1
        self.last_reason = why
        if not self.breached and self.outside_count >= max(1, count_needed):
            self.breached = True
            self.breaches += 1
            return why
        return None
