"""The fixed-wing ground–air task: orbit over the UGV team's centre of mass and keep every UGV
in a gimballed camera's view, behind the safety net.

Geometry (`plan_orbit`), all SI, NED:

    R = (V + s)² / (g · tan(k · φ_max))                                        (1)

the loiter radius a coordinated turn at airspeed V [m/s] and bank k·φ_max can hold about a
centre moving at up to s [m/s] (the speed relative to the centre peaks at V + s; k < 1 keeps
bank in reserve for the guidance's corrections). The camera looks at the centre of mass from
slant range D = √(R² + h²), depression ε = atan(h/R). A flat 1 m marker seen at that angle
spans about

    p(h) = f · m · sin ε / D = f · m · h / (R² + h²)   [px]                    (2)

across its short side, which peaks at h = R (45° look-down); so h = R clamped to the envelope's
altitude band. The team fits when its largest extent about the centre of mass, ρ ≤ 2r(n−1)/n for
n UGVs within r of the formation centre, subtends at most a fraction `fill` of the half short
side of the image:

    f · ρ / (D − ρ) ≤ fill · min(W, H) / 2                                     (3)

(the nearest UGV is at most ρ closer than the centre). (3) is a lower bound on the slant range,
D ≥ ρ (1 + f / (fill · min(W, H) / 2)), so on a steep bank limit (1) may give a circle too
small for the camera: the planner then widens it to the smallest R whose D meets (3) — a
shallower bank than k·φ_max, the one the orbit will command, atan((V + s)² / (g R)) — and
never beyond `radius_max_m` (the autopilot's hold circle the envelope allows). `plan_orbit`
raises ValueError when (3) or p ≥ `marker_px_min` still fails, with the numbers.

The companion that flies it is mission/orbit.py (OrbitMission): the centre as the camera sees
it, moved only as far as `circle_certified` holds (`slide_centre`), certified by the net
(`setpoint_certified`), the climb-out until it is.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.groundsim.ugv import UGVModel
from skyherd.perception.camera import CameraParams
from skyherd.perception.gimbal import ORBIT_CAMERA
from skyherd.safety.compiled import kernels
from skyherd.safety.envelope import NZ, P
from skyherd.safety.monitor import make_z
from skyherd.safety.supervisor import Supervisor


@dataclass(frozen=True)
class OrbitParams:
    """What the orbit planner needs (saved in config.json)."""

    airspeed_mps: float = 24.0  # V: the autopilot's FW_AIRSPD_TRIM [m/s]
    bank_max_rad: float = math.radians(35.0)  # φ_max: the autopilot's FW_R_LIM [rad]
    bank_fraction: float = 0.7  # k in (1): bank used by the steady orbit
    team_speed_mps: float = 3.0  # s: fastest the team's centre drives [m/s]
    team_radius_m: float = 10.0  # r: every UGV within r of the formation centre [m]
    n_ugvs: int = 3
    alt_min_m: float = 40.0  # altitude band the orbit may use [m] (envelope floor + margin)
    alt_max_m: float = 135.0  # (envelope ceiling − margin − altitude tolerance)
    fill: float = 0.8  # (3): share of the half short side the team may cover
    marker_m: float = UGVModel.marker_size_m  # UGV top marker side [m]
    marker_px_min: float = 2.0  # short side of a marker in the image at least [px]
    radius_max_m: float = math.inf  # the widest orbit allowed (the envelope's loiter reserve) [m]

    def __post_init__(self) -> None:
        vals = [self.airspeed_mps, self.bank_max_rad, self.bank_fraction, self.team_speed_mps,
                self.team_radius_m, self.alt_min_m, self.alt_max_m, self.fill, self.marker_m]  # fmt: skip
        if not all(math.isfinite(v) for v in vals):
            raise ValueError(f"orbit parameters must be finite: {self}")
        if not (self.airspeed_mps > 0 and 0 < self.bank_max_rad < math.pi / 2):
            raise ValueError("airspeed must be > 0 and bank_max in (0, 90°)")
        if not (0 < self.bank_fraction <= 1 and 0 < self.fill <= 1 and self.n_ugvs >= 1):
            raise ValueError("bank_fraction and fill must be in (0, 1], n_ugvs >= 1")
        if not (0 < self.alt_min_m < self.alt_max_m and self.team_speed_mps >= 0):
            raise ValueError("need 0 < alt_min_m < alt_max_m and team_speed_mps >= 0")
        if not self.radius_max_m > 0:
            raise ValueError("radius_max_m must be > 0")


@dataclass(frozen=True)
class OrbitPlan:
    """The orbit `plan_orbit` chose, with the figures that justify it."""

    radius_m: float  # R (1)
    altitude_m: float  # h
    slant_m: float  # D = √(R² + h²)
    depression_rad: float  # ε = atan(h / R)
    bank_rad: float  # steady bank about a still centre, atan(V² / (g R))
    extent_m: float  # ρ: largest UGV distance from the centre of mass
    team_px: float  # (3): f ρ / (D − ρ)
    team_px_max: float  # fill · min(W, H) / 2
    marker_px: float  # (2)
    bank_cmd_rad: float = math.nan  # the bank it commands at the worst, atan((V + s)² / (g R))


def turn_radius(airspeed_mps: float, bank_rad: float) -> float:
    """Radius [m] of a level coordinated turn: V² / (g tan φ)."""
    return airspeed_mps**2 / (GRAVITY * math.tan(bank_rad))


def camera_radius(d_min: float, alt_min: float, alt_max: float) -> float:
    """The smallest R [m] whose slant range √(R² + h²), h = R clamped to [alt_min, alt_max],
    reaches `d_min` [m] (0 when any R does): D grows with R, so each branch of the clamp is
    solved in closed form."""
    if d_min <= alt_min:
        return 0.0
    r = d_min / math.sqrt(2.0)
    if r < alt_min:
        return math.sqrt(d_min * d_min - alt_min * alt_min)
    if r > alt_max:
        return math.sqrt(d_min * d_min - alt_max * alt_max)
    return r


def plan_orbit(p: OrbitParams, cam: CameraParams = ORBIT_CAMERA) -> OrbitPlan:
    """Radius and altitude by (1)–(3): the turn (1) at k·φ_max, widened (a shallower bank) until
    the team fits (3) if it does not; ValueError when the camera still cannot hold the team."""
    rho = 2.0 * p.team_radius_m * (p.n_ugvs - 1) / p.n_ugvs if p.n_ugvs > 1 else 0.0
    rho = max(rho, 0.5 * p.marker_m)
    team_max = p.fill * 0.5 * min(cam.width_px, cam.height_px)
    vs = p.airspeed_mps + p.team_speed_mps
    r = turn_radius(vs, p.bank_fraction * p.bank_max_rad)
    r_cam = camera_radius(rho * (1.0 + cam.fx / team_max), p.alt_min_m, p.alt_max_m)
    if r_cam > r:  # (3) fails on the turn's circle: the smallest circle it holds on
        r = min(r_cam * (1.0 + 1e-9), max(p.radius_max_m, r))
    h = min(max(r, p.alt_min_m), p.alt_max_m)
    d = math.hypot(r, h)
    team_px = cam.fx * rho / max(d - rho, 1e-9)
    marker_px = cam.fx * p.marker_m * h / (r * r + h * h)
    plan = OrbitPlan(r, h, d, math.atan2(h, r), math.atan(p.airspeed_mps**2 / (GRAVITY * r)),
                     rho, team_px, team_max, marker_px, math.atan(vs * vs / (GRAVITY * r)))  # fmt: skip
    if r > p.radius_max_m * (1.0 + 1e-6):
        raise ValueError(
            f"the orbit's circle ({r:.0f} m at a bank of {math.degrees(p.bank_fraction * p.bank_max_rad):.0f}°) "
            f"is wider than the {p.radius_max_m:.0f} m the envelope allows the autopilot's loiter; "
            "raise the autopilot's bank limit or fly slower"
        )
    if team_px > team_max:
        raise ValueError(
            f"the team ({2 * rho:.0f} m across) does not fit the camera at {d:.0f} m: "
            f"{team_px:.0f} px > {team_max:.0f} px (its radius may be at most "
            f"{p.radius_max_m:.0f} m); widen the field of view"
        )
    if marker_px < p.marker_px_min:
        raise ValueError(
            f"UGV markers too small at {d:.0f} m: {marker_px:.1f} px < {p.marker_px_min:g} px; "
            "narrow the field of view or fly a smaller orbit"
        )
    return plan


def circle_certified(geometry, centre_ne, radius_m: float, alt_m: float, reserve_m: float,
                     margin_v_m: float = 0.0) -> bool:  # fmt: skip
    """The orbit (circle of `radius_m` about `centre_ne` (2,) at `alt_m` [m]) with `reserve_m`
    [m] all round — the disc of radius R + reserve — lies inside the fence: every row
    a·p <= b of the position-only envelope `geometry` holds over the whole disc,

        a_n c_n + a_e c_e − a_d h + (R + reserve)·|(a_n, a_e)| <= b  (− margin_v for the
        altitude rows, whose horizontal part is 0),

    under the envelope's union rules (one inclusion piece holds entirely, in every exclusion
    zone one face). Exact for the half-planes, so the disc test is conservative only across
    the splits of a non-convex fence."""
    a = geometry.A[:, P]
    hyp = np.hypot(a[:, 0], a[:, 1])
    b = geometry.b - (radius_m + reserve_m) * hyp - np.where(hyp < 1e-9, margin_v_m, 0.0)
    z = np.zeros(NZ)
    z[P] = (centre_ne[0], centre_ne[1], -alt_m)
    e = geometry
    w = kernels().worst_residual(e.A, b, z, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
    return bool(w <= 0.0)


def slide_centre(ok, centre: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, bool]:
    """The orbit centre toward `target` as far as the fence allows: `target` when `ok(target)`
    (its orbit certifies), else the farthest certified point on the segment from `centre`
    toward it (bisection, 12 halvings: < 0.03 % of the step), so it slides along the boundary of
    the certified region instead of stopping at its first touch; `centre` itself when that is
    not certified (the fence moved). Returns (new centre, held back by the fence)."""
    if ok(target):
        return np.asarray(target, float).copy(), False
    if not ok(centre):
        return centre, True
    lo, hi = 0.0, 1.0
    for _ in range(12):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(centre + mid * (target - centre)) else (lo, mid)
    return centre + lo * (target - centre), True


def setpoint_certified(sup: Supervisor, state: VehicleState, setpoint: Setpoint) -> bool:
    """Would the net accept `setpoint` at this state? The velocity it implies against the
    envelope; no supervisor state is changed (the climb-out's hand-over test)."""
    u = sup.implied_velocity(state, setpoint)
    return bool(sup.envelope.worst(make_z(state, u)) <= 0.0)


def fence_reserve(spec) -> float:
    """Distance [m] the orbit circle keeps from every fence row: the envelope's margin, its
    loiter-fallback diameter 2·R_turn(v_max) and the reaction-time run-on (dt + t_react)·v_max,
    the reserve the envelope's own fence rows demand of a fixed-wing (safety.envelope eq. 3),
    so an aircraft on the certified circle never trips the safety net."""
    lim, dyn = spec.limits, spec.dynamics
    v = lim.speed_h_mps
    return lim.margin_m + 2.0 * dyn.turn_radius(v) + (dyn.dt_s + dyn.react_s) * v
