"""Simplex supervisor: AI → FALLBACK → PID → AI, with the time passed in (PX4 commander style).

    decision = supervisor.update(t, state, proposed, health)

- AI: the AI's velocity command goes through if the monitor accepts it. In "project" mode an
  unsafe command is replaced by the closest safe one (if the QP finds one); otherwise, and for
  every non-recoverable fault, the supervisor switches to FALLBACK.
- FALLBACK: the airframe's fallback (hover / loiter); maps to the autopilot's own HOLD mode.
  After `hold_min_s` and once settled, → PID.
- PID: the recovery controller flies to a point inside the fence with a margin. The AI gets
  control back when the vehicle is there, its links are healthy, and every AI proposal of the
  last `hysteresis_s` was inside the envelope.
Faults: non-finite or out-of-range action, missed action deadline, lost camera, lost MAVLink
link, wind above the airframe's limit, a GPS jump, non-finite state, and any envelope row. Severity is ordered; the most severe wins.
Every switch is written to `events` (anything with `.write(dict)`, e.g. JsonlWriter).
"""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.runio.constants import POS_SPEED_MAX_MPS
from skyherd.safety.compiled import kernels
from skyherd.safety.envelope import CAMERA_TIMEOUT_S, NZ, Envelope
from skyherd.safety.fallback import (
    HoverFallback,
    LoiterFallback,
    PidGains,
    RecoveryPID,
    inside_with_margin,
)
from skyherd.safety.monitor import Monitor, make_z
from skyherd.safety.projection import Projector


class Mode(enum.Enum):
    AI = "ai"
    FALLBACK = "fallback"
    PID = "pid"


class Severity(enum.IntEnum):
    """Ordered: the more severe outcome wins when several checks fire."""

    NONE = 0
    NEAR = 1  # a constraint is nearly active; the action goes through
    PROJECTED = 2  # the action was replaced by the closest safe one
    FALLBACK = 3  # the airframe fallback takes over


DR_GAP_S = 1.0
"""A telemetry gap longer than this [s] restarts the GPS guard's dead reckoning."""


@dataclass(frozen=True)
class SupervisorParams:
    """Supervisor settings (saved with each run)."""

    intervention: str = (
        "switch"  # "switch": unsafe → FALLBACK; "project": closest safe action first
    )
    hysteresis_s: float = 2.0  # AI proposals must stay inside this long before it flies again [s]
    deadline_s: float = 0.3  # no new AI action for longer = policy stall [s]
    camera_timeout_s: float | None = CAMERA_TIMEOUT_S  # no camera frame for longer = lost [s]
    link_timeout_s: float | None = 1.5  # no MAVLink heartbeat for longer = link lost [s]
    hold_min_s: float = 1.0  # minimum time in FALLBACK before PID [s]
    settle_mps: float = 0.5  # hover fallback counts as settled below this speed [m/s]
    recover_margin_m: float = 6.0  # PID target: this far inside every position row [m]
    recover_tol_m: float = 1.5  # PID target reached within this distance [m]
    recover_speed_mps: float = 3.0  # PID horizontal speed limit [m/s]
    out_of_range_factor: float = 3.0  # |command| beyond factor × speed limit = out of range
    kp: float = 0.6  # PID gains, see safety.fallback.PidGains
    ki: float = 0.02
    kd: float = 0.2
    fixedwing_min_speed_mps: float = 12.0  # loiter speed floor for the fixed-wing fallback
    pos_gain_xy: float = 0.95  # the autopilot's MPC_XY_P: position setpoint → velocity [1/s]
    pos_gain_z: float = 1.0  # the autopilot's MPC_Z_P [1/s]
    pos_speed_max_mps: float = (
        POS_SPEED_MAX_MPS  # the autopilot's MPC_XY_VEL_MAX: position-mode speed [m/s]
    )
    loiter_radius_m: float = (
        0.0  # fixed-wing loiter radius about a position setpoint (0: turn radius)
    )
    gps_jump_m: float | None = None  # position vs dead reckoning beyond this = GPS glitch [m]
    wind_limit_mps: float | None = None  # the airframe's mean-wind limit [m/s] (see _wind_check)
    # The four guards (gps_jump_m, wind_limit_mps, link_timeout_s, camera_timeout_s): None = off;
    # a constraint-set file states each ([guards], safety.config)
    wind_mean_s: float = 5.0  # the mean wind: the autopilot's estimate low-passed this long [s]
    wind_tolerance_mps: float = 3.0  # the mean above the limit by more = FALLBACK [m/s]
    gps_blend_s: float = 5.0  # dead reckoning pulled to the position with this time constant [s]

    def __post_init__(self) -> None:
        if self.intervention not in ("switch", "project"):
            raise ValueError(
                f"supervisor.intervention must be 'switch' or 'project', got {self.intervention!r}"
            )
        for k in (
            "hysteresis_s",
            "deadline_s",
            "recover_tol_m",
            "recover_speed_mps",
            "gps_blend_s",
            "wind_mean_s",
        ):
            if not getattr(self, k) > 0:
                raise ValueError(f"supervisor.{k} must be > 0, got {getattr(self, k)}")
        if not self.wind_tolerance_mps >= 0:
            raise ValueError(
                f"supervisor.wind_tolerance_mps must be >= 0, got {self.wind_tolerance_mps}"
            )
        for k in ("camera_timeout_s", "link_timeout_s", "gps_jump_m", "wind_limit_mps"):
            v = getattr(self, k)
            if v is not None and not v > 0:
                raise ValueError(f"supervisor.{k} must be > 0 or None (off), got {v}")


@dataclass(frozen=True)
class Health:
    """Latest arrival times [s, simulation clock] of the inputs the AI relies on; None = the
    input is not monitored."""

    camera_t: float | None = None
    link_t: float | None = None
    params_fault: str = ""  # the autopilot's parameters disagree with the envelope (ParamGuard)
    hold_ok: bool = True  # the autopilot's own HOLD behaves as the envelope assumes (ParamGuard)
    wind_mps: float | None = None  # the autopilot's horizontal wind estimate [m/s] (MAVLink
    # WIND_COV / WIND); None = no estimate


@dataclass(frozen=True)
class Decision:
    """What leaves the safety net this step.

    `command` is what is flown (certified); `proposed` the AI action it was judged from (None:
    no new action this step, the held one was re-judged). `verdict` is one word of the
    per-decision record (LAYOUT.md): accepted | projected | rejected | fallback | pid."""

    command: Setpoint
    mode: Mode
    severity: Severity
    reason: str
    autopilot_mode: FlightMode  # HOLD while in FALLBACK (the autopilot's own hover / loiter)
    ai_rejected: bool  # a (new or held) AI action was not flown as proposed
    t: float = math.nan  # simulation time of the decision [s]
    proposed: Setpoint | None = None

    @property
    def verdict(self) -> str:
        if self.mode is Mode.FALLBACK:
            return "fallback"
        if self.mode is Mode.PID:
            return "pid"
        if self.severity is Severity.PROJECTED:
            return "projected"
        return "rejected" if self.ai_rejected else "accepted"

    def record(
        self,
        vehicle: str = "uav0",
        pilot: str = "policy",
        phi=None,
        autopilot_mode: FlightMode | str | None = None,
        explanation: dict | None = None,
        action: int | None = None,
    ) -> dict[str, Any]:
        """The per-decision record of LAYOUT.md (one line of decisions.jsonl), JSON-ready —
        the one record every writer of decisions uses and every reader reads.

        autopilot_mode: the mode the autopilot reports (heartbeat) or the net asked for;
        default the mode the supervisor wants it in. action: a learned policy's discrete action."""
        ap = autopilot_mode if autopilot_mode is not None else self.autopilot_mode
        rec: dict[str, Any] = {
            "t": None if not math.isfinite(self.t) else round(float(self.t), 6),
            "vehicle": vehicle,
            "pilot": pilot,
            "phi": None if phi is None else [float(x) for x in np.asarray(phi).ravel()],
            "proposed": setpoint_record(self.proposed),
            "certified": setpoint_record(self.command),
            "verdict": self.verdict,
            "reason": self.reason,
            "mode": self.mode.value,
            "autopilot_mode": ap.name if isinstance(ap, FlightMode) else str(ap),
        }
        if action is not None:
            rec["action"] = action
        if explanation is not None:
            rec["explanation"] = explanation
        return rec


def setpoint_record(sp: Setpoint | None) -> dict[str, Any]:
    """{"pos_ned", "vel_ned", "yaw"} of a setpoint as lists / floats / None (non-finite kept
    as None so that the record stays valid JSON)."""

    def vec(v):
        if v is None:
            return None
        try:
            a = np.asarray(v, dtype=float).ravel()
        except (TypeError, ValueError):
            return None
        a = a.tolist()
        if math.isfinite(sum(a)):  # every entry finite (a NaN or inf shows in the sum)
            return a
        return [x if math.isfinite(x) else None for x in a]

    if sp is None:
        return {"pos_ned": None, "vel_ned": None, "yaw": None}
    yaw = sp.yaw
    try:
        yaw = None if yaw is None or not math.isfinite(float(yaw)) else float(yaw)
    except (TypeError, ValueError):
        yaw = None
    return {"pos_ned": vec(sp.pos_ned), "vel_ned": vec(sp.vel_ned), "yaw": yaw}


class EventSink(Protocol):
    def write(self, record: dict[str, Any]) -> None: ...


@dataclass
class SupervisorStats:
    """Counters for the drill table."""

    switches: int = 0
    rejected: int = 0
    projected: int = 0
    near: int = 0
    fallback_s: float = 0.0
    pid_s: float = 0.0
    reasons: list[str] = field(default_factory=list)  # reason of each switch to FALLBACK
    projected_reasons: list[str] = field(default_factory=list)  # distinct rows projections fixed


class Supervisor:
    """The Simplex switch. One instance per vehicle; not thread-safe."""

    def __init__(
        self,
        envelope: Envelope,
        params: SupervisorParams = SupervisorParams(),
        events: EventSink | None = None,
    ):
        self.envelope = envelope
        self.geometry = envelope.spec.geometry()
        self.p = params
        self.events = events
        self.monitor = Monitor(envelope)
        self.projector = Projector(envelope) if params.intervention == "project" else None
        spec = envelope.spec
        self.airframe = spec.airframe
        if spec.dynamics.bank_max_rad > 0:
            self.fallback: HoverFallback | LoiterFallback = LoiterFallback(
                spec.dynamics.bank_max_rad, self.geometry, params.fixedwing_min_speed_mps
            )
        else:
            self.fallback = HoverFallback(params.settle_mps)
        self.pid = RecoveryPID(
            PidGains(params.kp, params.ki, params.kd),
            self.geometry,
            params.recover_speed_mps,
            params.recover_margin_m,
            min_speed_mps=params.fixedwing_min_speed_mps if spec.dynamics.bank_max_rad > 0 else 0.0,
        )
        self.max_cmd = params.out_of_range_factor * max(
            spec.limits.speed_h_mps, spec.limits.climb_mps, spec.limits.descent_mps
        )
        self.loiter_radius_m = params.loiter_radius_m  # the orbit sets NAV_LOITER_RAD's value
        self.mode = Mode.AI
        self.mode_since = 0.0
        self.clean_since: float | None = None
        self.last_action_t: float | None = None
        self.last_u: np.ndarray | None = None
        self.last_sp: Setpoint | None = None  # the last well-formed AI action (yaw, position)
        self._dyn_A: np.ndarray | None = None  # rows that change every step (separation)
        self._dyn_b = np.zeros(0)
        self._dyn_names: tuple[str, ...] = ()
        self._p_dr: np.ndarray | None = None  # dead-reckoned position (GPS glitch guard)
        self._dr_t: float | None = None
        self._dr_pv: tuple[np.ndarray, np.ndarray] | None = None  # the last sample judged
        self._dr_why = ""
        self.position_suspect = False
        self.wind_high = False  # the mean wind is above the airframe's limit (_wind_check)
        self.wind_mean: float | None = None  # [m/s]
        self._wind_t: float | None = None
        self.last_t: float | None = None
        self.stats = SupervisorStats()
        self._z = np.zeros(NZ)
        e = envelope
        self._args = (e.A, e.b, self._z, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
        self._near_args = (
            e.A,
            e.b,
            self._z,
            e.near,
            e.n_base,
            e.n_piece_end,
            e.piece_starts,
            e.zone_starts,
        )

    # ------------------------------------------------------------------ checks
    def _judge(
        self, t: float, state: VehicleState, proposed: Setpoint | None, health: Health
    ) -> tuple[Severity, str, np.ndarray | None]:
        """Severity and reason for the AI's (new or held) action at this state; the command it
        would fly (projected in project mode), or None."""
        p = self.p
        z = make_z(state, None, out=self._z)  # state part; z[U] = 0 until the action is known
        if not _finite(z):
            return Severity.FALLBACK, "non-finite vehicle state", None
        self._wind_check(t, health.wind_mps)
        lt, ct = p.link_timeout_s, p.camera_timeout_s
        if lt is not None and health.link_t is not None and t - health.link_t > lt:
            return Severity.FALLBACK, f"MAVLink link lost ({t - health.link_t:.1f} s)", None
        if ct is not None and health.camera_t is not None and t - health.camera_t > ct:
            return Severity.FALLBACK, f"camera lost ({t - health.camera_t:.1f} s)", None
        if health.params_fault:
            return Severity.FALLBACK, f"autopilot parameters: {health.params_fault}", None
        if self.wind_high:
            return (
                Severity.FALLBACK,
                f"wind {self.wind_mean:.1f} m/s (mean) above the airframe's limit "
                f"{p.wind_limit_mps:g} m/s",
                None,
            )
        jump = self._position_check(state)
        if jump:
            return Severity.FALLBACK, jump, None
        if proposed is not None:
            self.last_action_t = t
            why = self._accept_action(proposed)
            if why:
                return Severity.FALLBACK, why, None
        if self.last_action_t is None or t - self.last_action_t > p.deadline_s:
            since = self.last_action_t if self.last_action_t is not None else self.mode_since
            return (
                Severity.FALLBACK,
                f"action deadline missed ({t - since:.2f} s > {p.deadline_s:g} s)",
                None,
            )
        if self.last_sp is not None and self.last_sp.pos_ned is not None:
            self.last_u = self.implied_velocity(state, self.last_sp)  # what the autopilot flies
        u = self.last_u
        if u is None:
            return Severity.FALLBACK, "malformed action (no velocity command)", None
        u0, u1, u2 = u.tolist()
        if not (math.isfinite(u0) and math.isfinite(u1) and math.isfinite(u2)):
            return Severity.FALLBACK, "non-finite action (NaN/inf)", None
        big = max(abs(u0), abs(u1), abs(u2))
        if big > self.max_cmd:
            return (
                Severity.FALLBACK,
                f"action out of range ({big:.3g} m/s > {self.max_cmd:g})",
                None,
            )
        z[8], z[9], z[10] = u0, u1, u2
        if self._dyn_A is not None and len(self._dyn_b):
            r = self._dyn_A @ z - self._dyn_b
            i = int(r.argmax())
            if not r[i] <= 0.0:  # NaN too
                return Severity.FALLBACK, self._dyn_names[i], None
        k = kernels()  # looked up per call: a build made after this net was, once there, is used
        w = k.worst_residual(*self._args)
        if w <= 0.0:
            i = k.nearest_active(*self._near_args)
            if i >= 0:
                return Severity.NEAR, self.envelope.names[i], u
            return Severity.NONE, "", u
        viol = self.envelope.violated(z)
        name = viol[0][0] if viol else "non-finite state or action"
        if self.projector is not None:
            up = self.projector.project(z.copy())
            if up is not None:
                return Severity.PROJECTED, name, up
        return Severity.FALLBACK, name, None

    def set_dynamic_rows(self, A: np.ndarray, b: np.ndarray, names: tuple[str, ...]) -> None:
        """Extra rows A z <= b (A (m, NZ)) that hold until replaced, checked like base rows
        (all must hold) before the envelope; e.g. the separation from other vehicles
        (safety.separation). A violated row is a FALLBACK with its name."""
        A = np.asarray(A, float).reshape(-1, NZ)
        self._dyn_A, self._dyn_b, self._dyn_names = (
            A,
            np.asarray(b, float).reshape(-1),
            tuple(names),
        )

    def _wind_check(self, t: float, wind_mps: float | None) -> None:
        """Wind guard: the mean wind w̄ (the autopilot's estimate, Health.wind_mps, low-passed
        with wind_mean_s) against the airframe's limit L, the mean wind its envelope was stated
        for with gusts of σ <= 2 m/s (τ 2 s) on top: such gusts move w̄ with σ √(2/(2 + 5)) =
        1.1 m/s, so w̄ > L + wind_tolerance_mps (3 m/s, 3 σ) sets `wind_high` (FALLBACK, held:
        no PID, no AI), cleared at w̄ <= L. A wind within the statement does not trip it (a
        12 m/s mean with 2 m/s gusts in `skyherd fly`: no switch); a steady wind w > L + tol
        trips wind_mean_s · ln((w − w₀)/(w − L − tol)) after it rose from w₀ (12 → 16 m/s:
        6.9 s, 12 → 20: 2.3 s) plus the estimate's own 1 s. Between L and L + tol in flight it
        is not caught (before the flight `skyherd fly` refuses a mean above L). No estimate
        (None, non-finite): w̄ kept, not judged further."""
        p = self.p
        if wind_mps is None or not math.isfinite(wind_mps) or p.wind_limit_mps is None:
            return
        if self.wind_mean is None or self._wind_t is None:
            self.wind_mean = wind_mps
        else:
            k = min(max(t - self._wind_t, 0.0) / p.wind_mean_s, 1.0)
            self.wind_mean += k * (wind_mps - self.wind_mean)
        self._wind_t = t
        if self.wind_mean > p.wind_limit_mps + p.wind_tolerance_mps:
            self.wind_high = True
        elif self.wind_mean <= p.wind_limit_mps:
            self.wind_high = False

    def _position_check(self, state: VehicleState) -> str:
        """GPS glitch guard: the position must agree with the dead-reckoned one.

        p_dr(t) = p_dr(t−dt) + dt · v(t)   (velocity from the inertial estimate, which a GPS
        step does not move), pulled toward the measured position with time constant
        gps_blend_s while they agree. |p − p_dr| > gps_jump_m is a position fault (FALLBACK)
        that lasts until the position returns within gps_jump_m of the dead reckoning; the
        dead reckoning is not pulled while it lasts. Assumption: a step ≥ gps_jump_m is a
        glitch; a drift slower than gps_jump_m / gps_blend_s is not seen here (the margin and
        the autopilot's EKF innovation gate must cover it)."""
        p = self.p
        if p.gps_jump_m is None:
            return ""
        pos, t = state.pos_ned, float(state.t)
        if (
            self._dr_pv is not None
            and np.array_equal(self._dr_pv[0], pos)
            and np.array_equal(self._dr_pv[1], state.vel_ned)
        ):
            # the same sample again (a companion's state keeps the last LOCAL_POSITION_NED
            # while its clock runs on with other messages, e.g. through a cut link): no news,
            # the dead reckoning waits for the next sample (a gap > DR_GAP_S restarts it)
            return self._dr_why
        self._dr_pv = (np.array(pos, float), np.array(state.vel_ned, float))
        self._dr_why = self._dr_step(pos, state.vel_ned, t)
        return self._dr_why

    def _dr_step(self, pos: np.ndarray, vel: np.ndarray, t: float) -> str:
        p = self.p
        if (
            self._p_dr is None
            or self._dr_t is None
            or not np.all(np.isfinite(self._p_dr))
            or t - self._dr_t > DR_GAP_S
        ):
            # first state, or telemetry came back after a gap (a cut link): the dead reckoning
            # has no basis across the gap (the vehicle braked, turned, held meanwhile), so it
            # starts again here; a step hidden inside a gap is not seen (the margin covers it)
            self._p_dr, self._dr_t = np.array(pos, float), t
            self.position_suspect = False
            return ""
        dt = max(t - self._dr_t, 0.0)
        self._dr_t = t
        self._p_dr = self._p_dr + dt * np.asarray(vel, float)
        innov = pos - self._p_dr
        e = float(np.linalg.norm(innov))
        if e > p.gps_jump_m:
            self.position_suspect = True
            return f"position jumped {e:.1f} m from the dead-reckoned one (GPS glitch?)"
        self.position_suspect = False
        self._p_dr = self._p_dr + min(dt / p.gps_blend_s, 1.0) * innov
        return ""

    def _accept_action(self, proposed: Setpoint) -> str:
        """Validate a new AI action and keep it (last_sp, last_u); the fault reason or ""."""
        self.last_sp = None
        if not isinstance(proposed, Setpoint):
            self.last_u = None
            return "malformed action (not a Setpoint)"
        u = proposed.vel_ned
        if u is None and proposed.pos_ned is None:
            self.last_u = None
            return "malformed action (no velocity or position command)"
        if u is not None:
            try:
                u = np.asarray(u, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                self.last_u = None
                return "malformed action (velocity not numeric)"
            if u.shape != (3,):
                self.last_u = None
                return f"malformed action (velocity of shape {u.shape})"
        bad = _bad_extras(proposed)
        if bad:
            self.last_u = np.full(3, math.nan)  # held as a non-finite action
            return f"non-finite action ({bad})"
        self.last_u = u
        self.last_sp = proposed
        return ""

    def implied_velocity(self, state: VehicleState, sp: Setpoint) -> np.ndarray:
        """The velocity [m/s NED] the autopilot flies for a position setpoint, which is what
        the net certifies (docs/safety.md, "Position setpoints"):

        multirotor (PX4 position loop):  u = v_ff + K (p_sp − p),  K = diag(kxy, kxy, kz)
            with kxy = MPC_XY_P, kz = MPC_Z_P (SupervisorParams.pos_gain_xy / pos_gain_z),
            horizontal part clipped at pos_speed_max_mps (MPC_XY_VEL_MAX);
        fixed-wing (loiter about p_sp, radius `loiter_radius_m`, clockwise like the
            autopilot): the course the loiter vector field asks for, reached no faster than a
            turn at the envelope's bank limit over the velocity loop's time constant,
            Δψ ≤ τ g tan(φ_max) / V, at the present airspeed; vertical as the multirotor."""
        p = self.p
        pos = np.asarray(sp.pos_ned, float)
        (x0, x1, x2), (y0, y1, y2) = pos.tolist(), np.asarray(state.pos_ned, float).tolist()
        e0, e1, e2 = x0 - y0, x1 - y1, x2 - y2  # e = p_sp − p
        f0, f1, f2 = (
            (0.0, 0.0, 0.0) if sp.vel_ned is None else np.asarray(sp.vel_ned, float).tolist()
        )
        lim = self.envelope.spec.limits
        vd = min(max(f2 + p.pos_gain_z * e2, -lim.climb_mps), lim.descent_mps)
        dyn = self.envelope.spec.dynamics
        if dyn.bank_max_rad <= 0:
            u0, u1 = f0 + p.pos_gain_xy * e0, f1 + p.pos_gain_xy * e1
            h = float(np.hypot(u0, u1))  # numpy's hypot: math.hypot differs in the last bit
            if h > p.pos_speed_max_mps:
                s = p.pos_speed_max_mps / h
                u0, u1 = u0 * s, u1 * s
            return np.array([u0, u1, vd])
        v = state.vel_ned[:2]
        speed = max(float(np.hypot(v[0], v[1])), p.fixedwing_min_speed_mps)
        radius = self.loiter_radius_m or dyn.turn_radius(speed)
        r = state.pos_ned[:2] - pos[:2]
        d = float(np.hypot(r[0], r[1]))
        if d < 1e-6:
            want = v
        else:
            rad = r / d
            tangent = np.array([-rad[1], rad[0]])  # clockwise seen from above
            want = tangent - 1.5 * (d - radius) / radius * rad
        psi_v = (
            math.atan2(v[1], v[0]) if np.hypot(v[0], v[1]) > 0.5 else math.atan2(want[1], want[0])
        )
        step = dyn.tau_s * GRAVITY * math.tan(dyn.bank_max_rad) / speed
        dpsi = (math.atan2(want[1], want[0]) - psi_v + math.pi) % (2 * math.pi) - math.pi
        psi = psi_v + max(-step, min(step, dpsi))
        return np.array([speed * math.cos(psi), speed * math.sin(psi), vd])

    # ------------------------------------------------------------------ update
    def update(
        self, t: float, state: VehicleState, proposed: Setpoint | None, health: Health = Health()
    ) -> Decision:
        """One control step at simulation time t [s]; `proposed` None = no new AI action."""
        if self.last_t is None:
            self.mode_since = t
            if self.last_action_t is None and proposed is None:
                self.last_action_t = t  # the deadline counts from the first update
        dt = 0.0 if self.last_t is None else max(t - self.last_t, 0.0)
        self.last_t = t
        if self.mode is Mode.FALLBACK:
            self.stats.fallback_s += dt
        elif self.mode is Mode.PID:
            self.stats.pid_s += dt
        sev, reason, u = self._judge(t, state, proposed, health)
        rejected = sev >= Severity.PROJECTED
        if sev == Severity.NEAR:
            self.stats.near += 1

        if self.mode is Mode.AI:
            if sev == Severity.FALLBACK:
                self._switch(t, Mode.FALLBACK, reason, sev, state)
            else:
                if sev == Severity.PROJECTED:
                    self.stats.projected += 1
                    if reason not in self.stats.projected_reasons:
                        self.stats.projected_reasons.append(reason)
                if rejected and proposed is not None:
                    self.stats.rejected += 1
                return Decision(
                    self._ai_command(u, sev), Mode.AI, sev, reason, FlightMode.OFFBOARD, rejected,
                    t, proposed,
                )  # fmt: skip

        if self.mode is not Mode.AI and proposed is not None:
            self.stats.rejected += 1  # while the safety net flies, AI actions are not flown
            rejected = True
        if sev == Severity.FALLBACK:
            self.clean_since = None
        elif self.clean_since is None and sev <= Severity.NEAR:
            self.clean_since = t

        if self.mode is Mode.PID and (self.position_suspect or health.params_fault
                                      or self.wind_high):  # fmt: skip
            # the recovery flies positions in OFFBOARD: not on a suspect position estimate, on
            # parameters that disagree with the envelope, nor in a wind beyond what the
            # envelope's braking assumes
            self._switch(t, Mode.FALLBACK, reason, Severity.FALLBACK, state)
        if self.mode is Mode.FALLBACK:
            if (
                t - self.mode_since >= self.p.hold_min_s
                and self.fallback.settled(state)
                and not health.params_fault  # only the autopilot's own HOLD is consistent
                and not self.position_suspect
                and not self.wind_high
            ):
                self._switch(
                    t,
                    Mode.PID,
                    f"fallback settled after {t - self.mode_since:.1f} s",
                    Severity.NONE,
                    state,
                )
            else:
                cmd, ap_mode = self._fallback_command(state, health)
                return Decision(
                    self._keep_yaw(cmd),
                    Mode.FALLBACK,
                    max(sev, Severity.FALLBACK),
                    reason or "holding",
                    ap_mode,
                    rejected,
                    t,
                    proposed,
                )

        # Mode.PID; the position tests (pure) only when the AI's proposals would qualify
        clean = self.clean_since is not None and t - self.clean_since >= self.p.hysteresis_s
        if (
            clean
            and sev < Severity.PROJECTED
            and (
                self.pid.error(state) <= self.p.recover_tol_m  # there
                or inside_with_margin(
                    self.geometry, state.pos_ned, self.p.recover_margin_m - self.p.recover_tol_m
                )
            )
        ):
            self._switch(
                t,
                Mode.AI,
                f"AI proposals inside for {t - self.clean_since:.1f} s; vehicle inside with margin",
                Severity.NONE,
                state,
            )
            return Decision(
                self._ai_command(u, sev), Mode.AI, sev, "", FlightMode.OFFBOARD, False, t, proposed
            )
        return Decision(
            self._keep_yaw(self.pid.command(t, state)),
            Mode.PID,
            sev,
            reason or "recovering",
            FlightMode.OFFBOARD,
            rejected,
            t,
            proposed,
        )

    def _keep_yaw(self, cmd: Setpoint) -> Setpoint:
        """The fallback and the recovery fly no heading of their own: they keep the AI's last
        yaw (the net bounds translation, not heading; a formation or a camera keeps its yaw)."""
        last = self.last_sp
        if cmd.yaw is not None or cmd.yaw_rate is not None or last is None or last.yaw is None:
            return cmd
        return dataclasses.replace(cmd, yaw=last.yaw)

    def _fallback_command(self, state: VehicleState, health: Health) -> tuple[Setpoint, FlightMode]:
        """The fallback's command and the mode it is flown in. Normally the autopilot's own
        HOLD. A multirotor with a suspect position (GPS glitch) holds zero *velocity* in
        OFFBOARD instead: the autopilot's HOLD would fly its glitched position estimate. When
        the autopilot's hold itself disagrees with the envelope (its loiter radius, its
        braking: Health.hold_ok False), the net's own fallback is flown in OFFBOARD."""
        if self.position_suspect and self.envelope.spec.dynamics.bank_max_rad <= 0:
            return Setpoint(vel_ned=np.zeros(3)), FlightMode.OFFBOARD
        if not health.hold_ok:
            cmd = self.fallback.command(state)
            return cmd, FlightMode.OFFBOARD
        return self.fallback.command(state), FlightMode.HOLD

    def _ai_command(self, u: np.ndarray, sev: Severity) -> Setpoint:
        """What flies in AI mode: the AI's own setpoint (its position, yaw and yaw rate kept)
        when its velocity was accepted as proposed; the projected velocity with the AI's yaw
        when the net replaced it (a position setpoint would undo the projection, so it goes)."""
        sp = self.last_sp
        yaw = None if sp is None else sp.yaw
        rate = None if sp is None else sp.yaw_rate
        if sev == Severity.PROJECTED or sp is None:
            return Setpoint(vel_ned=u.copy(), yaw=yaw, yaw_rate=rate)
        if sp.pos_ned is None:
            return Setpoint(vel_ned=u.copy(), yaw=yaw, yaw_rate=rate)
        # a position setpoint flies as proposed: its feed-forward, not the implied velocity
        ff = None if sp.vel_ned is None else np.asarray(sp.vel_ned, float).copy()
        return Setpoint(pos_ned=np.asarray(sp.pos_ned, float).copy(), vel_ned=ff, yaw=yaw,
                        yaw_rate=rate)  # fmt: skip

    def _switch(self, t: float, to: Mode, reason: str, sev: Severity, state: VehicleState) -> None:
        frm = self.mode
        self.mode = to
        self.mode_since = t
        self.stats.switches += 1
        if to is Mode.FALLBACK:
            self.fallback.engage(state)
            self.clean_since = None
            self.stats.reasons.append(reason)
        elif to is Mode.PID:
            self.pid.engage(state)
            self.clean_since = None
        if self.events is not None:
            roll, pitch, yaw = state.euler if np.all(np.isfinite(state.quat)) else (math.nan,) * 3
            self.events.write(
                {
                    "t": round(t, 6),
                    "event": "switch",
                    "from": frm.value,
                    "to": to.value,
                    "reason": reason,
                    "severity": sev.name,
                    "envelope_version": self.envelope.version,
                    "state": {
                        "pos_ned": state.pos_ned,
                        "vel_ned": state.vel_ned,
                        "roll_pitch_yaw": [roll, pitch, yaw],
                    },
                    "action": None if self.last_u is None else self.last_u,
                    "pid_target": self.pid.target if to is Mode.PID else None,
                }
            )


def _bad_extras(sp: Setpoint) -> str:
    """Why the yaw, yaw rate or position of an action is unusable ("" if fine)."""
    for name, v in (("yaw", sp.yaw), ("yaw rate", sp.yaw_rate)):
        if v is None:
            continue
        try:
            f = float(v)
        except (TypeError, ValueError):
            return f"{name} not numeric"
        if not (math.isfinite(f) and abs(f) <= 100.0):
            return f"{name} {f}"
    if sp.pos_ned is not None:
        try:
            p = np.asarray(sp.pos_ned, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            return "position not numeric"
        if p.shape != (3,) or not all(map(math.isfinite, p.tolist())):
            return "position setpoint not 3 finite numbers"
    return ""


def _finite(z: np.ndarray) -> bool:
    return math.isfinite(z.sum())  # one reduction: a NaN or inf anywhere shows in the sum
