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
link, non-finite state, and any envelope row. Severity is ordered; the most severe wins.
Every switch is written to `events` (anything with `.write(dict)`, e.g. JsonlWriter).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from flight.autopilot_api import FlightMode, Setpoint
from flight.state import VehicleState
from safety.envelope import NZ, Envelope
from safety.fallback import HoverFallback, LoiterFallback, PidGains, RecoveryPID, inside_with_margin
from safety.kernels import nearest_active, worst_residual
from safety.monitor import Monitor, make_z
from safety.projection import Projector


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


@dataclass(frozen=True)
class SupervisorParams:
    """Supervisor settings (saved with each run)."""

    intervention: str = (
        "switch"  # "switch": unsafe → FALLBACK; "project": closest safe action first
    )
    hysteresis_s: float = 2.0  # AI proposals must stay inside this long before it flies again [s]
    deadline_s: float = 0.3  # no new AI action for longer = policy stall [s]
    camera_timeout_s: float = 1.0  # no camera frame for longer = camera lost [s]
    link_timeout_s: float = 1.5  # no MAVLink heartbeat for longer = link lost [s]
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

    def __post_init__(self) -> None:
        if self.intervention not in ("switch", "project"):
            raise ValueError(
                f"supervisor.intervention must be 'switch' or 'project', got {self.intervention!r}"
            )
        for k in (
            "hysteresis_s",
            "deadline_s",
            "camera_timeout_s",
            "link_timeout_s",
            "recover_tol_m",
            "recover_speed_mps",
        ):
            if not getattr(self, k) > 0:
                raise ValueError(f"supervisor.{k} must be > 0, got {getattr(self, k)}")


@dataclass(frozen=True)
class Health:
    """Latest arrival times [s, simulation clock] of the inputs the AI relies on; None = the
    input is not monitored."""

    camera_t: float | None = None
    link_t: float | None = None


@dataclass(frozen=True)
class Decision:
    """What leaves the safety net this step."""

    command: Setpoint
    mode: Mode
    severity: Severity
    reason: str
    autopilot_mode: FlightMode  # HOLD while in FALLBACK (the autopilot's own hover / loiter)
    ai_rejected: bool  # a (new or held) AI action was not flown as proposed


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
        self.mode = Mode.AI
        self.mode_since = 0.0
        self.clean_since: float | None = None
        self.last_action_t: float | None = None
        self.last_u: np.ndarray | None = None
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
        if health.link_t is not None and t - health.link_t > p.link_timeout_s:
            return Severity.FALLBACK, f"MAVLink link lost ({t - health.link_t:.1f} s)", None
        if health.camera_t is not None and t - health.camera_t > p.camera_timeout_s:
            return Severity.FALLBACK, f"camera lost ({t - health.camera_t:.1f} s)", None
        if proposed is not None:
            self.last_action_t = t
            u = proposed.vel_ned
            if u is None:
                self.last_u = None
                return Severity.FALLBACK, "malformed action (no velocity command)", None
            try:
                u = np.asarray(u, dtype=float).reshape(-1)
            except (TypeError, ValueError):
                self.last_u = None
                return Severity.FALLBACK, "malformed action (velocity not numeric)", None
            if u.shape != (3,):
                self.last_u = None
                return Severity.FALLBACK, f"malformed action (velocity of shape {u.shape})", None
            self.last_u = u
        if self.last_action_t is None or t - self.last_action_t > p.deadline_s:
            since = self.last_action_t if self.last_action_t is not None else self.mode_since
            return (
                Severity.FALLBACK,
                f"action deadline missed ({t - since:.2f} s > {p.deadline_s:g} s)",
                None,
            )
        u = self.last_u
        if u is None:
            return Severity.FALLBACK, "malformed action (no velocity command)", None
        u0, u1, u2 = float(u[0]), float(u[1]), float(u[2])
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
        w = worst_residual(*self._args)
        if w <= 0.0:
            i = nearest_active(*self._near_args)
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
                    Setpoint(vel_ned=u.copy()), Mode.AI, sev, reason, FlightMode.OFFBOARD, rejected
                )

        if self.mode is not Mode.AI and proposed is not None:
            self.stats.rejected += 1  # while the safety net flies, AI actions are not flown
            rejected = True
        if sev == Severity.FALLBACK:
            self.clean_since = None
        elif self.clean_since is None and sev <= Severity.NEAR:
            self.clean_since = t

        if self.mode is Mode.FALLBACK:
            if t - self.mode_since >= self.p.hold_min_s and self.fallback.settled(state):
                self._switch(
                    t,
                    Mode.PID,
                    f"fallback settled after {t - self.mode_since:.1f} s",
                    Severity.NONE,
                    state,
                )
            else:
                return Decision(
                    self.fallback.command(state),
                    Mode.FALLBACK,
                    max(sev, Severity.FALLBACK),
                    reason or "holding",
                    FlightMode.HOLD,
                    rejected,
                )

        # Mode.PID
        there = self.pid.error(state) <= self.p.recover_tol_m
        inside = inside_with_margin(
            self.geometry, state.pos_ned, self.p.recover_margin_m - self.p.recover_tol_m
        )
        clean = self.clean_since is not None and t - self.clean_since >= self.p.hysteresis_s
        if (there or inside) and clean and sev < Severity.PROJECTED:
            self._switch(
                t,
                Mode.AI,
                f"AI proposals inside for {t - self.clean_since:.1f} s; vehicle inside with margin",
                Severity.NONE,
                state,
            )
            return Decision(
                Setpoint(vel_ned=u.copy()), Mode.AI, sev, "", FlightMode.OFFBOARD, False
            )
        return Decision(
            self.pid.command(t, state),
            Mode.PID,
            sev,
            reason or "recovering",
            FlightMode.OFFBOARD,
            rejected,
        )

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


def _finite(z: np.ndarray) -> bool:
    return bool(np.isfinite(z.sum()))  # one reduction: a NaN or inf anywhere shows in the sum
