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

Companion (`OrbitCompanion.update`, once per telemetry sample, simulation time):
1. the UGV team moves to time t; its centre of mass c(t) is the orbit centre;
2. at the camera rate the gimbal points at c(t); the frame is rendered, published, detected;
3. every decision period the orbit is certified: the circle about c(t) at altitude h must lie
   inside the fence with `fence_reserve` (else the centre moves toward c(t) only as far as
   that holds), and the safety net's supervisor judges the state and the velocity the orbit
   flies (present horizontal velocity, climb toward h). AI → an offboard position setpoint
   (c, −h) that the autopilot loiters about with radius R (NAV_LOITER_RAD); FALLBACK → the
   autopilot's own HOLD (a loiter); PID → the supervisor's recovery velocity.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flight.autopilot_api import FlightMode, Setpoint
from flight.frames import quat_to_euler
from flight.geo import GRAVITY
from flight.state import VehicleState
from groundsim.ugv import UGVModel, UGVStates
from hil.orbit_gimbal import GimbalParams, gimbal_pose
from perception.camera import CameraParams, camera_pose, in_image, project
from perception.pipeline import CameraRig, CameraTick
from safety.envelope import NZ, P
from safety.kernels import worst_residual
from safety.monitor import make_z
from safety.supervisor import Decision, Health, Supervisor

# The zoomed gimbal camera: 320×240 like the quadrotor's, 20° horizontal field of view
# (f = 907 px): a 1 m marker spans ~3 px at ~190 m slant range, a 20 m team fits in 1/3 of H.
ORBIT_CAMERA = CameraParams(hfov_rad=math.radians(20.0), mount_offset_frd=(0.0, 0.0, 0.0))


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
    w = worst_residual(e.A, b, z, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
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


@dataclass
class OrbitSample:
    """One camera frame of the orbit: what the camera saw and where everything was."""

    t: float
    pos_ned: np.ndarray  # aircraft (3,) [m]
    centre_ne: np.ndarray  # UGV centre of mass (2,) [m]
    orbit_ne: np.ndarray  # the orbit centre commanded (2,) [m] (= centre_ne unless fenced)
    ugvs_ne: np.ndarray  # (n, 2) [m]
    detected: int  # UGVs the detector found
    all_detected: bool  # φ all_in_view
    all_projected: bool  # every UGV's true position projects inside the image
    body_fixed: bool  # ... would, for the same camera fixed to the body looking down
    bank_rad: float
    tilt_rad: float
    mode: str  # the safety net's mode at this frame


class OrbitCompanion:
    """Camera on a gimbal → perception; orbit centre → safety net → setpoint (module docstring)."""

    def __init__(self, plan: OrbitPlan, team, supervisor: Supervisor, rig: CameraRig,
                 reserve_m: float, decision_dt_s: float = 0.2,
                 gimbal: GimbalParams | None = None, climb_tau_s: float = 5.0,
                 world=None):  # fmt: skip
        self.plan, self.team, self.supervisor, self.rig = plan, team, supervisor, rig
        self.world = world  # a groundsim GroundWorld mirrored for PyBullet pixels, or None
        self.reserve_m, self.decision_dt_s = reserve_m, decision_dt_s
        self.margin_v_m = supervisor.envelope.spec.limits.margin_m  # ceiling and floor
        supervisor.loiter_radius_m = plan.radius_m  # the autopilot's NAV_LOITER_RAD
        self.gimbal = gimbal if gimbal is not None else GimbalParams()
        self.climb_tau_s = climb_tau_s
        lim = supervisor.envelope.spec.limits
        self.climb_max, self.descent_max = lim.climb_mps, lim.descent_mps
        self.t0: float | None = None
        self.t_ground = 0.0
        self.t_frame: float | None = None
        self.t_decision: float | None = None
        self.last_tick: CameraTick | None = None
        self.centre = self.team_centre()  # certified orbit centre (2,)
        self.switches_at_est = 0  # supervisor switches when the orbit was established
        self.limited = 0  # decisions where the fence held the centre short of the com
        self.decision: Decision | None = None
        self.samples: list[OrbitSample] = []

    def team_states(self) -> UGVStates:
        pos = np.array(self.team.positions(), dtype=float)
        vn, ve = getattr(self.team, "centre_velocity", (0.0, 0.0))
        n = len(pos)
        return UGVStates(pos, np.full(n, math.atan2(ve, vn)), np.full(n, math.hypot(vn, ve)),
                         np.zeros(n, dtype=bool))  # fmt: skip

    def team_centre(self) -> np.ndarray:
        """The UGVs' centre of mass (2,) NE [m] (equal masses)."""
        return np.mean(np.array(self.team.positions(), dtype=float), axis=0)

    def _camera(self, t: float, state: VehicleState) -> None:
        if not self.rig.due(t):
            return
        ugvs = self.team_states()
        com = np.array([*np.mean(ugvs.pos_ne, axis=0), 0.0])
        roll, _, yaw = quat_to_euler(state.quat)
        gp = gimbal_pose(self.rig.cam, state.pos_ned, yaw, com, self.gimbal)
        if self.world is not None:
            self.world.place(ugvs)  # PyBullet pixels of the same team
        tick = self.rig.tick(t, gp, ugvs)
        if tick is None:
            return
        self.last_tick, self.t_frame = tick, t
        pose = camera_pose(self.rig.cam, gp.pos_ned, gp.quat)
        pts = np.column_stack([ugvs.pos_ne, np.zeros(len(ugvs.pos_ne))])
        uv, _ = project(self.rig.cam, pose, pts)
        uv_body, _ = project(
            self.rig.cam, camera_pose(self.rig.cam, state.pos_ned, state.quat), pts
        )
        mode = self.supervisor.mode.value
        self.samples.append(
            OrbitSample(t, state.pos_ned.copy(), com[:2], self.centre.copy(), ugvs.pos_ne.copy(),
                        len(tick.detections.centroids_px),
                        bool(tick.phi[5] > 0.5), bool(in_image(self.rig.cam, uv).all()),
                        bool(in_image(self.rig.cam, uv_body).all()),
                        roll, gp.tilt_rad, mode)
        )  # fmt: skip

    def proposal(self, state: VehicleState) -> Setpoint:
        """What the orbit flies: the position setpoint (orbit centre, −h) that the autopilot
        loiters about with radius R. The safety net certifies the motion it implies (a
        bank-limited turn onto the loiter circle, the climb toward h: Supervisor.implied_velocity)."""
        return Setpoint(pos_ned=np.array([self.centre[0], self.centre[1], -self.plan.altitude_m]))

    def certified_now(self, state: VehicleState) -> bool:
        """Would the net accept the orbit's setpoint at this state? (No supervisor state is
        changed: the hand-over test of `climb_out`.)"""
        return self._ok(self.centre) and setpoint_certified(self.supervisor, state,
                                                             self.proposal(state))  # fmt: skip

    def update(self, t: float, state: VehicleState, link_t: float | None = None) -> Decision:
        """Vehicle time t [s] and state → the certified decision to fly now. link_t: the
        link's freshness from safety.health.HealthTracker (what arrived); None = this
        telemetry sample, which just arrived."""
        if self.t0 is None:
            self.t0 = t
        dt = (t - self.t0) - self.t_ground
        if dt > 0:
            self.team.step(dt)
            self.t_ground += dt
        self._camera(t, state)
        proposed = None
        if self.t_decision is None or t - self.t_decision >= self.decision_dt_s - 1e-9:
            self.t_decision = t
            self._move_centre(self.team_centre())
            proposed = self.proposal(state)
        health = Health(camera_t=self.t_frame, link_t=t if link_t is None else link_t)
        self.decision = self.supervisor.update(t, state, proposed, health)
        return self.decision

    def _ok(self, c: np.ndarray) -> bool:
        return circle_certified(self.supervisor.geometry, c, self.plan.radius_m,
                                self.plan.altitude_m, self.reserve_m, self.margin_v_m)  # fmt: skip

    def _move_centre(self, com: np.ndarray) -> None:
        """The orbit centre follows the centre of mass as far as the fence allows (slide_centre)."""
        self.centre, held = slide_centre(self._ok, self.centre, com)
        self.limited += held

    def setpoint(self) -> tuple:
        """(pos_ned, vel_ned, yaw) for the offboard stream from the last decision."""
        d = self.decision
        if d is None:
            return np.array([self.centre[0], self.centre[1], -self.plan.altitude_m]), None, None
        return d.command.pos_ned, d.command.vel_ned, d.command.yaw  # AI: the certified setpoint

    @property
    def wants_hold(self) -> bool:
        return self.decision is not None and self.decision.autopilot_mode is FlightMode.HOLD


def climb_out(client, comp: OrbitCompanion, vehicle_time, hold_s: float = 3.0,
              timeout_s: float = 300.0, resend_s: float = 5.0) -> float:  # fmt: skip
    """The climb-out, flown by the autopilot, planned into the envelope: after the take-off
    (which ends far out on the runway heading, beyond the fixed-wing's certified region — the
    fence minus the loiter reserve), DO_REPOSITION sends the aircraft's own loiter to the
    orbit's centre at the orbit's altitude; the AI gets the vehicle only once the net
    certifies the orbit's setpoint at the present state, continuously for `hold_s` s of
    vehicle time. Returns the vehicle time of that moment; ClientTimeout after `timeout_s`."""
    from hil.client import ClientTimeout

    tel = client.telemetry
    target = np.array([comp.centre[0], comp.centre[1], -comp.plan.altitude_m])
    t0 = vehicle_time()
    sent, since = -math.inf, None
    while True:
        t = vehicle_time()
        if t - sent >= resend_s:
            client.link.send(client.reposition_message(target))
            sent = t
        client.wait_message("LOCAL_POSITION_NED", timeout=5.0)
        vs = tel.vehicle_state()
        ok = vs is not None and comp.certified_now(vs)
        since = (since if since is not None else t) if ok else None
        if since is not None and t - since >= hold_s:
            return t
        if t - t0 > timeout_s:
            raise ClientTimeout(f"climb-out: the orbit was not certified within {timeout_s:.0f} s")
