"""The flight envelope as linear constraints A·z <= b over the state and the proposed command.

The vector z (shape (NZ,) = (11,)), NED about home, SI units:

    z[0:3]  p = position north, east, down        [m]
    z[3:6]  v = velocity north, east, down        [m/s]
    z[6:8]  roll, pitch (ZYX Euler)                [rad]
    z[8:11] u = proposed velocity command N, E, D  [m/s]

One-step prediction model (first-order velocity loop with time constant tau, period dt):

    alpha = min(dt / tau, 1)
    v' = (1 - alpha) v + alpha u                            (1)
    p' = p + dt v'                                          (2)

A position constraint n·p <= d (unit normal n) is checked at the predicted state, pushed
ahead by a stopping distance that is linear in the velocity:

    n·p' + T n·v' <= d - margin                             (3)

T = v_max / (2 a_dec) + t_react is the chord of the braking curve s^2 / (2 a_dec) over
[0, v_max]: for any closing speed 0 <= s <= v_max, s^2/(2 a_dec) + s t_react <= T s, so a
vehicle that satisfied (3) can always brake to a stop before the fence. Equation (3) is
linear in z because (1) and (2) are. A fixed-wing cannot stop: it loiters, so its T is only
the reaction time and the loiter circle's diameter 2 R_turn is added to the margin.

The feasible set is a union of polyhedra: all *base* rows must hold, the position must be
inside at least one convex piece of the inclusion fence, and outside every exclusion zone
(outside a convex zone = at least one of its faces, reversed, holds). A non-convex fence is
split into convex pieces; the splits are not fences, so their rows carry the prediction
(the stop point may cross into the next piece) but no margin.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.geo import GRAVITY
from skyherd.safety.geometry import (
    circle_polygon,
    convex_pieces,
    half_planes,
    outer_edges,
    validate_polygon,
)


def _kernels():
    """The compiled kernels (safety.compiled), looked up on first use: loading or checking an
    envelope (`skyherd fly` validating its file) loads none."""
    from skyherd.safety.compiled import kernels

    return kernels()


CAMERA_TIMEOUT_S = 1.0  # the camera guard's default: no frame for longer = camera lost [s]
NZ = 11
P, V, ATT, U = slice(0, 3), slice(3, 6), slice(6, 8), slice(8, 11)


class Kind(enum.IntEnum):
    """What a constraint row limits; also selects its 'nearly active' threshold."""

    FENCE = 0
    EXCLUSION = 1
    ALTITUDE = 2
    HOME = 3
    SPEED = 4
    ACCEL = 5
    ATTITUDE = 6
    STATE_SPEED = 7


POSITION_KINDS = (Kind.FENCE, Kind.EXCLUSION, Kind.ALTITUDE, Kind.HOME)


@dataclass(frozen=True)
class Dynamics:
    """The envelope's prediction model of the airframe (eq. 1-3)."""

    dt_s: float = 0.02  # control period [s]
    tau_s: float = 0.5  # velocity-loop time constant [s]
    decel_h_mps2: float = (
        3.0  # horizontal braking the fallback can count on [m/s^2]; 0 = cannot stop
    )
    decel_v_mps2: float = 2.0  # vertical braking [m/s^2]
    react_s: float = 0.3  # detection + switching delay [s]
    bank_max_rad: float = 0.0  # fixed-wing: bank limit of the loiter [rad]; 0 = can hover
    sink_reserve_m: float = 0.0  # height a gust may take before the climb answers it [m]
    # (the floor row keeps it on top of the margin; fixed-wing rule in fixedwing_field.toml)

    def turn_radius(self, speed_mps: float) -> float:
        """Loiter radius R = v^2 / (g tan(bank_max)) [m] at horizontal speed v (0 if it hovers)."""
        if self.bank_max_rad <= 0:
            return 0.0
        return speed_mps * speed_mps / (GRAVITY * math.tan(self.bank_max_rad))


@dataclass(frozen=True)
class Limits:
    """Envelope limits. Angles in rad, speeds m/s, accelerations m/s^2, distances m."""

    ceiling_m: float = 60.0  # altitude above home
    floor_m: float = 5.0
    speed_h_mps: float = 8.0
    climb_mps: float = 3.0
    descent_mps: float = 2.0
    accel_h_mps2: float = 4.0
    accel_v_mps2: float = 3.0
    tilt_cmd_rad: float = 0.61  # tilt a command may demand: |a_h| <= g tan(tilt)
    attitude_max_rad: float = 0.79  # measured roll / pitch beyond this is a violation
    state_speed_factor: float = 1.25  # measured speed beyond factor × limit is a violation
    home_radius_m: float = 0.0  # 0 = no home radius
    circle_sides: int = 16  # sides of the polygons that stand for circles
    speed_sides: int = 8  # sides of the polygons that stand for |v_h| and |a_h|
    margin_m: float = 2.0  # kept between the predicted stop and the fence
    near_m: float = 5.0  # a position row within this is "nearly active"
    breach_tolerance_m: float = 0.0  # ground truth beyond the fence by more = a breach


@dataclass(frozen=True)
class Guards:
    """The run-time guards of a constraint set (the file's [guards] table states every one;
    safety.config). None = stated off. Each is judged by the supervisor (safety.supervisor)."""

    gps_jump_m: float | None = None  # position vs dead reckoning beyond this = GPS glitch [m]
    wind_limit_mps: float | None = None  # the airframe's mean-wind limit [m/s]: above it
    # `skyherd fly` refuses to start and, in flight, the net flies the airframe's fallback
    link_timeout_s: float | None = None  # no MAVLink heartbeat / telemetry longer = lost [s]
    camera_timeout_s: float | None = None  # no camera frame longer = camera lost [s]


@dataclass(frozen=True)
class Zone:
    """A named polygon (north, east) [m], shape (n, 2)."""

    name: str
    points: np.ndarray = field(repr=False)


@dataclass(frozen=True)
class EnvelopeSpec:
    """Everything a constraint set file says: the source of both envelopes."""

    name: str
    version: str
    airframe: str
    dynamics: Dynamics
    limits: Limits
    inclusions: tuple[Zone, ...] = ()
    exclusions: tuple[Zone, ...] = ()
    source: str = ""  # file or "fence items" it came from
    guards: Guards = Guards()  # a file states every one; built in code: all off

    def envelope(self) -> Envelope:
        """The predictive envelope the monitor checks actions against (eq. 3)."""
        return build(self, predictive=True)

    def geometry(self) -> Envelope:
        """Position-only envelope at zero margin: where the vehicle really must stay."""
        return build(self, predictive=False)

    def stop_times(self) -> tuple[float, float, float]:
        """T of eq. 3 for horizontal, upward and downward motion [s]."""
        d, lim = self.dynamics, self.limits
        th = d.react_s + (lim.speed_h_mps / (2 * d.decel_h_mps2) if d.decel_h_mps2 > 0 else 0.0)
        tu = d.react_s + lim.climb_mps / (2 * d.decel_v_mps2)
        td = d.react_s + lim.descent_mps / (2 * d.decel_v_mps2)
        return th, tu, td

    def describe(self) -> dict:
        """Plain summary for config.json."""
        return {
            "name": self.name,
            "version": self.version,
            "airframe": self.airframe,
            "source": self.source,
            "dynamics": self.dynamics,
            "limits": self.limits,
            "guards": self.guards,
            "inclusions": {z.name: z.points.tolist() for z in self.inclusions},
            "exclusions": {z.name: z.points.tolist() for z in self.exclusions},
        }


@dataclass(frozen=True)
class Envelope:
    """Rows A (m, NZ), b (m,), each with a name and kind; grouped as base | pieces | zones.

    Rows [0, n_base) must all hold; rows [n_base, n_piece_end) are the inclusion pieces
    (starting at `piece_starts`, one must hold entirely); the rest are exclusion-zone faces
    (starting at `zone_starts`, in each zone one must hold).
    """

    spec: EnvelopeSpec
    A: np.ndarray
    b: np.ndarray
    names: tuple[str, ...]
    kinds: np.ndarray
    near: np.ndarray
    n_base: int
    n_piece_end: int
    piece_starts: np.ndarray  # relative to n_base
    zone_starts: np.ndarray  # relative to n_piece_end
    piece_names: tuple[str, ...]
    zone_names: tuple[str, ...]

    @property
    def version(self) -> str:
        return self.spec.version

    @property
    def m(self) -> int:
        return len(self.b)

    def residual(self, z: np.ndarray) -> np.ndarray:
        """A z - b (m,): > 0 violated, in each row's own unit (m, m/s, m/s^2, rad)."""
        return self.A @ z - self.b

    def worst(self, z: np.ndarray) -> float:
        """Largest violation of the union-of-polyhedra test; <= 0 means z is allowed.

        z: (NZ,) float64. NaN when z is not finite. Compiled: ~1 µs.
        """
        return _kernels().worst_residual(
            self.A, self.b, z, self.n_base, self.n_piece_end, self.piece_starts, self.zone_starts
        )

    def worst_of(self, r: np.ndarray) -> float:
        """The same test from residuals r (m,) in numpy (reference for the compiled one)."""
        if not np.all(np.isfinite(r)):
            return math.nan
        w = r[: self.n_base].max() if self.n_base else -math.inf
        if self.n_piece_end > self.n_base:
            w = max(
                w, np.maximum.reduceat(r[self.n_base : self.n_piece_end], self.piece_starts).min()
            )
        if self.m > self.n_piece_end:
            w = max(w, np.minimum.reduceat(r[self.n_piece_end :], self.zone_starts).max())
        return float(w)

    def select(self, r: np.ndarray) -> np.ndarray:
        """Row indices of the one polyhedron that `r` is judged against: the base rows, the
        inclusion piece with the smallest worst residual, and per zone its best face."""
        rows = [np.arange(self.n_base)]
        if self.n_piece_end > self.n_base:
            seg = r[self.n_base : self.n_piece_end]
            ends = np.append(self.piece_starts[1:], len(seg))
            best = int(np.argmin(np.maximum.reduceat(seg, self.piece_starts)))
            rows.append(self.n_base + np.arange(self.piece_starts[best], ends[best]))
        if self.m > self.n_piece_end:
            seg = r[self.n_piece_end :]
            ends = np.append(self.zone_starts[1:], len(seg))
            for s, e in zip(self.zone_starts, ends):
                rows.append(np.array([self.n_piece_end + s + int(np.argmin(seg[s:e]))]))
        return np.concatenate(rows)

    def violated(self, z: np.ndarray) -> list[tuple[str, float]]:
        """Violated rows of the selected polyhedron, worst first: [(name, residual)]."""
        r = self.residual(z)
        if not np.all(np.isfinite(r)):
            return [("non-finite state or action", math.nan)]
        sel = self.selected(r)
        bad = sel[r[sel] > 0]
        bad = bad[np.argsort(-r[bad])]
        return [(self.names[i], float(r[i])) for i in bad]

    def nearly_active(self, z: np.ndarray) -> list[tuple[str, float]]:
        """Rows of the selected polyhedron within their `near` threshold of the limit."""
        r = self.residual(z)
        if not np.all(np.isfinite(r)):
            return []
        sel = self.selected(r)
        hit = sel[(r[sel] > -self.near[sel]) & (r[sel] <= 0)]
        return [(self.names[i], float(r[i])) for i in hit[np.argsort(-r[hit])]]

    def selected(self, r: np.ndarray) -> np.ndarray:
        """`select(r)` from the compiled kernels.select_mask (the same rows in the same order,
        tested against it): what the net's checks use at run time, `select` is the reference."""
        k = _kernels()
        return np.flatnonzero(
            k.select_mask(r, self.n_base, self.n_piece_end, self.piece_starts, self.zone_starts)
        )

    def distance_outside(self, p_ned: np.ndarray) -> float:
        """For a position-only (geometric) envelope: metres beyond the fence (<= 0 inside)."""
        z = np.zeros(NZ)
        z[P] = p_ned
        return self.worst(z)


def build(spec: EnvelopeSpec, predictive: bool) -> Envelope:
    """Assemble the rows of `spec` (see the module docstring for eq. 1-3)."""
    lim, dyn = spec.limits, spec.dynamics
    alpha = min(dyn.dt_s / dyn.tau_s, 1.0) if dyn.tau_s > 0 else 1.0
    th, tu, td = spec.stop_times()
    extra_h = 2.0 * dyn.turn_radius(lim.speed_h_mps)
    rows: list[tuple[np.ndarray, float, str, Kind]] = []

    def pos_row(
        n3: np.ndarray,
        d: float,
        t_stop: float,
        extra: float,
        name: str,
        kind: Kind,
        margin: bool = True,
    ):
        a = np.zeros(NZ)
        a[P] = n3
        if predictive:
            k = dyn.dt_s + t_stop
            a[V] = k * (1 - alpha) * n3
            a[U] = k * alpha * n3
            d = d - (lim.margin_m + extra if margin else 0.0)
        return a, d, name, kind

    # --- base rows: altitude, home radius, speed, acceleration/tilt, attitude, state speed
    rows.append(
        pos_row(
            np.array([0, 0, -1.0]),
            lim.ceiling_m,
            tu,
            0.0,
            f"ceiling {lim.ceiling_m:g} m",
            Kind.ALTITUDE,
        )
    )
    rows.append(
        pos_row(
            np.array([0, 0, 1.0]),
            -lim.floor_m,
            td,
            dyn.sink_reserve_m,
            f"floor {lim.floor_m:g} m",
            Kind.ALTITUDE,
        )
    )
    if lim.home_radius_m > 0:
        n, d = half_planes(
            circle_polygon(np.zeros(2), lim.home_radius_m, lim.circle_sides, outer=False)
        )
        for i, (ni, di) in enumerate(zip(n, d)):
            rows.append(
                pos_row(
                    np.array([ni[0], ni[1], 0.0]),
                    di,
                    th,
                    extra_h,
                    f"home radius {lim.home_radius_m:g} m (side {i + 1})",
                    Kind.HOME,
                )
            )
    if predictive:
        ks = lim.speed_sides
        cosk = math.cos(math.pi / ks)
        a_h = min(lim.accel_h_mps2, GRAVITY * math.tan(lim.tilt_cmd_rad))
        a_h_name = (
            f"tilt {math.degrees(lim.tilt_cmd_rad):.0f} deg"
            if a_h < lim.accel_h_mps2
            else f"horizontal accel {lim.accel_h_mps2:g} m/s2"
        )
        for i in range(ks):
            ang = 2 * math.pi * i / ks
            c = np.array([math.cos(ang), math.sin(ang), 0.0])
            deg = f"{math.degrees(ang):.0f} deg"
            a = np.zeros(NZ)
            a[U] = c
            rows.append(
                (
                    a,
                    lim.speed_h_mps * cosk,
                    f"horizontal speed {lim.speed_h_mps:g} m/s ({deg})",
                    Kind.SPEED,
                )
            )
            a = np.zeros(NZ)
            a[U], a[V] = c / dyn.tau_s, -c / dyn.tau_s
            rows.append((a, a_h * cosk, f"{a_h_name} ({deg})", Kind.ACCEL))
            a = np.zeros(NZ)
            a[V] = c
            vs = lim.state_speed_factor * lim.speed_h_mps
            rows.append((a, vs, f"measured horizontal speed {vs:g} m/s ({deg})", Kind.STATE_SPEED))
        for sgn, lab, lim_v in (
            (1.0, "descent rate", lim.descent_mps),
            (-1.0, "climb rate", lim.climb_mps),
        ):
            a = np.zeros(NZ)
            a[U][2] = sgn
            rows.append((a, lim_v, f"{lab} {lim_v:g} m/s", Kind.SPEED))
            a = np.zeros(NZ)
            a[U][2], a[V][2] = sgn / dyn.tau_s, -sgn / dyn.tau_s
            rows.append(
                (
                    a,
                    lim.accel_v_mps2,
                    f"vertical accel {lim.accel_v_mps2:g} m/s2 ({'down' if sgn > 0 else 'up'})",
                    Kind.ACCEL,
                )
            )
            a = np.zeros(NZ)
            a[V][2] = sgn
            vs = lim.state_speed_factor * lim_v
            rows.append((a, vs, f"measured {lab} {vs:g} m/s", Kind.STATE_SPEED))
        for j, lab in ((6, "roll"), (7, "pitch")):
            for sgn in (1.0, -1.0):
                a = np.zeros(NZ)
                a[j] = sgn
                rows.append(
                    (
                        a,
                        lim.attitude_max_rad,
                        f"{lab} {math.degrees(lim.attitude_max_rad):.0f} deg",
                        Kind.ATTITUDE,
                    )
                )
    n_base = len(rows)

    # --- inclusion fence: convex pieces, one must hold
    piece_starts, piece_names = [], []
    for zone in spec.inclusions:
        pieces = convex_pieces(zone.points)
        for k, piece in enumerate(pieces):
            piece_starts.append(len(rows) - n_base)
            pname = zone.name if len(pieces) == 1 else f"{zone.name} piece {k + 1}"
            piece_names.append(pname)
            n, d = half_planes(piece)
            real = outer_edges(piece, zone.points)
            for i, (ni, di) in enumerate(zip(n, d)):
                if real[i]:
                    rows.append(
                        pos_row(
                            np.array([ni[0], ni[1], 0.0]),
                            di,
                            th,
                            extra_h,
                            f"{pname} edge {i + 1}",
                            Kind.FENCE,
                        )
                    )
                else:  # a split between pieces: the stop point may cross it, with no margin
                    rows.append(
                        pos_row(
                            np.array([ni[0], ni[1], 0.0]),
                            di,
                            th,
                            0.0,
                            f"{pname} split {i + 1}",
                            Kind.FENCE,
                            margin=False,
                        )
                    )
    n_piece_end = len(rows)

    # --- exclusion zones: outside = one reversed face holds (convex zones only)
    zone_starts, zone_names = [], []
    for zone in spec.exclusions:
        for k, piece in enumerate(convex_pieces(zone.points)):
            zone_starts.append(len(rows) - n_piece_end)
            zname = zone.name if k == 0 else f"{zone.name} piece {k + 1}"
            zone_names.append(zname)
            n, d = half_planes(piece)
            for i, (ni, di) in enumerate(zip(n, d)):
                rows.append(
                    pos_row(
                        np.array([-ni[0], -ni[1], 0.0]),
                        -di,
                        th,
                        extra_h,
                        f"{zname} face {i + 1}",
                        Kind.EXCLUSION,
                    )
                )

    A = np.array([r[0] for r in rows]).reshape(-1, NZ)
    b = np.array([r[1] for r in rows], dtype=float)
    kinds = np.array([int(r[3]) for r in rows], dtype=np.int64)
    near = np.where(
        np.isin(kinds, [int(k) for k in POSITION_KINDS]),
        lim.near_m,
        np.where(kinds == Kind.ATTITUDE, 0.1, 0.1 * np.abs(b) + 1e-3),
    )
    return Envelope(
        spec=spec,
        A=np.ascontiguousarray(A),
        b=b,
        names=tuple(r[2] for r in rows),
        kinds=kinds,
        near=near,
        n_base=n_base,
        n_piece_end=n_piece_end,
        piece_starts=np.array(piece_starts, dtype=np.intp),
        zone_starts=np.array(zone_starts, dtype=np.intp),
        piece_names=tuple(piece_names),
        zone_names=tuple(zone_names),
    )


def circle_zone(
    name: str, center_ne: np.ndarray, radius_m: float, sides: int, exclusion: bool
) -> Zone:
    """A circle as a polygon: circumscribed for an exclusion (contains the circle), inscribed
    for an inclusion (inside the circle) — both conservative."""
    if not (radius_m > 0 and math.isfinite(radius_m)):
        raise ValueError(f"{name}: circle radius must be > 0, got {radius_m}")
    pts = circle_polygon(np.asarray(center_ne, float), radius_m, sides, outer=exclusion)
    return Zone(name, pts)


def polygon_zone(name: str, points_ne) -> Zone:
    return Zone(name, validate_polygon(np.asarray(points_ne, dtype=float), name))


class SignedDistance:
    """Exact signed distance [m] of a position to the envelope's boundary (> 0 outside).

    Inside, it is minus the distance to the nearest real boundary: fence and zone edges as
    segments (not the lines of their rows, and not the splits between convex pieces), the
    home-radius polygon, floor and ceiling. Outside, it is the row measure of `geometry()`.
    Drills use it for the "excursion" column; a non-convex fence needs the segment form.
    """

    def __init__(self, spec: EnvelopeSpec):
        self.spec = spec
        self.geometry = spec.geometry()
        rings = [z.points for z in spec.inclusions] + [z.points for z in spec.exclusions]
        if spec.limits.home_radius_m > 0:
            rings.append(
                circle_polygon(
                    np.zeros(2), spec.limits.home_radius_m, spec.limits.circle_sides, outer=False
                )
            )
        a = np.concatenate([r for r in rings]) if rings else np.zeros((0, 2))
        b = np.concatenate([np.roll(r, -1, axis=0) for r in rings]) if rings else np.zeros((0, 2))
        self.a, self.ab = a, b - a
        self.ab2 = np.maximum(np.einsum("ij,ij->i", self.ab, self.ab), 1e-12)

    def __call__(self, p_ned: np.ndarray) -> float:
        out = self.geometry.distance_outside(p_ned)
        if out > 0 or not math.isfinite(out):
            return out
        q = np.asarray(p_ned[:2], float)
        s = np.clip(np.einsum("ij,ij->i", q - self.a, self.ab) / self.ab2, 0.0, 1.0)
        d_h = (
            float(np.min(np.hypot(*(self.a + s[:, None] * self.ab - q).T)))
            if len(self.a)
            else math.inf
        )
        alt = -float(p_ned[2])
        d_v = min(alt - self.spec.limits.floor_m, self.spec.limits.ceiling_m - alt)
        return -min(d_h, d_v)
