"""The safety net beside an autopilot: the one wiring every loop flies (the missions of
`skyherd companion`, the orbit, the formation, the drills).

    net = SafetyNet.load("quadrotor", events=run.events())   # constraint set → supervisor
    net.load_params(t, params)          # the autopilot's parameters vs the envelope
    net.handover(t, ap_mode)            # the companion switched to OFFBOARD / GUIDED (accepted)
    # per arrival (simulation time of the tick it arrived in):
    net.link(heartbeat_t, telemetry_t); net.frame(t, stamp_t); net.param(t, name, value)
    net.restores(t)                     # {name: value} to PARAM_SET back (a sabotage undone)
    net.observe(t, mode, armed)         # every HEARTBEAT mode / arming change, in order
    d = net.step(t, state, proposal)    # Decision: command, mode, verdict, reason
    want = net.request(d)               # the mode to ask the autopilot for now, or None

`SafetyNet` owns the four parts — the supervisor (safety.supervisor), the health producer
(safety.health.HealthTracker), the parameter guard (safety.consistency.ParamGuard) and the
authority rules (safety.authority) — and it is the only place that builds the supervisor's
`Health` (`health()`) and the only place that maps a decision onto an autopilot mode
(`autopilot_mode_for`). Transports (MAVLink in mission/, the in-process autopilot in the
drills: `apply_decision`) only carry what it decides.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from skyherd.flight.autopilot_api import Autopilot, FlightMode, ModeSource, Result, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.safety.authority import NET_MODES, Authority
from skyherd.safety.compiled import ensure_built
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.consistency import ParamGuard
from skyherd.safety.fallback import inside_with_margin
from skyherd.safety.health import HealthParams, HealthTracker
from skyherd.safety.supervisor import (
    Decision,
    EventSink,
    Health,
    Mode,
    Supervisor,
    SupervisorParams,
)


def load_net(
    airframe: str,
    path: Path | str | None = None,
    events: EventSink | None = None,
    **overrides,
) -> Supervisor:
    """A Supervisor for `airframe` from its constraint-set file (default
    safety/envelopes/<airframe>_field.toml) and the file's [supervisor] table, with keyword
    overrides of SupervisorParams. Raises EnvelopeFileError / ValueError with a one-line reason."""
    spec, table = load_envelope(path if path is not None else default_envelope_path(airframe))
    if spec.airframe != airframe:
        raise ValueError(f"constraint set {spec.source} is for {spec.airframe}, not {airframe}")
    params = fill_dataclass(SupervisorParams, {**table, **overrides}, "supervisor")
    return Supervisor(spec.envelope(), params, events)


def autopilot_mode_for(d: Decision, use_autopilot_hold: bool = True) -> FlightMode:
    """The autopilot mode a decision is flown in — the one decision → mode mapping.

    FALLBACK with a consistent hold (the supervisor says HOLD) → the autopilot's own position
    hold (PX4 Hold, ArduCopter BRAKE, ArduPlane LOITER: the profile names the number); every
    other decision (AI, its projection, the recovery PID, a fallback flown as a setpoint
    because the autopilot's hold is not trusted) → OFFBOARD (ArduPilot: GUIDED)."""
    hold = d.mode is Mode.FALLBACK and use_autopilot_hold and d.autopilot_mode is FlightMode.HOLD
    return FlightMode.HOLD if hold else FlightMode.OFFBOARD


def apply_decision(
    ap: Autopilot, d: Decision, use_autopilot_hold: bool = True, authority: Authority | None = None
) -> Result:
    """Carry a decision to an in-process autopilot (the drills): the mode of
    `autopilot_mode_for`, the command streamed unless that mode is the autopilot's own HOLD —
    as long as the net has authority.

    With an `authority` (safety.authority) the autopilot's reported mode is observed first; a
    mode the net did not ask for ends the AI's authority and nothing is sent, ever again
    (until someone else gives OFFBOARD back). Without one, the net still never switches away
    from a mode it could not have set (RTL, LAND, a manual mode, MISSION, ...)."""
    t = float(ap.clock.t)
    want = autopilot_mode_for(d, use_autopilot_hold)
    if authority is not None:
        authority.observe(t, ap.mode)
        if not authority.has_authority:
            return Result.denied(f"the net has no authority: {authority.reason}")
    elif ap.mode not in NET_MODES:
        return Result.denied(f"the autopilot is in {ap.mode.name}: the net does not override it")
    r = Result.accepted() if want is FlightMode.HOLD else ap.set_offboard_setpoint(d.command)
    if not r.ok:
        return r
    ask = authority.request(want) if authority is not None else (want if ap.mode != want else None)
    if ask is None:
        return r
    r = ap.set_mode(ask, ModeSource.COMPANION)
    if authority is not None and r.temporary:
        authority.refused(t, ask, r.reason)  # the autopilot's failsafe holds the vehicle
    elif authority is not None:
        authority.requested(t, ask, r.ok)
        authority.observe(t, ap.mode)  # in-process the switch is immediate
    return r


class SafetyNet:
    """The safety net of one vehicle: supervisor, health from arrivals, parameter guard and
    authority, wired once (pure; time passed in; not thread-safe).

    Feed it what arrives (`link`/`message`, `frame`, `param`, `observe`) and call `step` once
    per tick; `step` returns the Decision (its `record()` is the decisions.jsonl line).
    `request(d)` is the mode to ask the autopilot for now (None: nothing to ask, or the net has
    no authority). Before `handover` it commands nothing; `handover_ok()` says whether it may
    (parameters consistent).

    camera: the camera is an input of the AI (the ground-air and orbit missions); from the
    hand-over on, a camera that delivers no fresh frame for `camera_timeout_s` is a fault, the
    first frame included. use_autopilot_hold: the fallback is the autopilot's own hold (True)
    or the fallback's setpoint streamed in OFFBOARD (a formation: K vehicles holding by their
    own rule would each wait out their mode switch beside the others)."""

    def __init__(self, supervisor: Supervisor, events: EventSink | None = None,
                 vehicle: str = "uav0", camera: bool = True,
                 health: HealthParams | None = None, use_autopilot_hold: bool = True):  # fmt: skip
        self.supervisor = supervisor
        self.events = events
        self.vehicle = vehicle
        self.use_autopilot_hold = use_autopilot_hold
        self.authority = Authority(events, vehicle)
        self.tracker = HealthTracker(health or HealthParams(), camera=camera)
        self.params = ParamGuard(supervisor.envelope.spec, supervisor.p.pos_speed_max_mps,
                                 events, vehicle)  # fmt: skip

    @classmethod
    def load(cls, airframe: str, path: Path | str | None = None,
             events: EventSink | None = None, overrides: Mapping | None = None,
             **kwargs) -> SafetyNet:  # fmt: skip
        """A net from a constraint-set file (load_net), with SafetyNet's keyword arguments."""
        return cls(load_net(airframe, path, events, **dict(overrides or {})), events, **kwargs)

    def set_events(self, events: EventSink | None) -> None:
        """Where every part writes its events (switches, hand-over and yields, parameters)."""
        self.events = self.supervisor.events = self.authority.events = events
        self.params.events = events

    # ---- what the supervisor is built on ------------------------------------------------------
    @property
    def envelope(self):
        return self.supervisor.envelope

    @property
    def spec(self):
        return self.supervisor.envelope.spec

    @property
    def p(self) -> SupervisorParams:
        return self.supervisor.p

    @property
    def mode(self) -> Mode:
        return self.supervisor.mode

    @property
    def stats(self):
        return self.supervisor.stats

    # ---- inputs: what arrived, at the simulation time of its arrival --------------------------
    def message(self, t: float, msg_type: str) -> None:
        self.tracker.message(t, msg_type)

    def link(self, heartbeat_t: float | None, telemetry_t: float | None) -> None:
        """The newest autopilot HEARTBEAT and position telemetry arrival times [s] (None: none
        yet), as a companion that keeps them per vehicle has them."""
        if heartbeat_t is not None:
            self.tracker.message(heartbeat_t, "HEARTBEAT")
        if telemetry_t is not None:
            self.tracker.message(telemetry_t, "LOCAL_POSITION_NED")

    def frame(self, t: float, stamp_t: float | None = None) -> None:
        self.tracker.frame(t, stamp_t)

    def load_params(self, t: float, params: Mapping[str, float]) -> str:
        return self.params.load(t, params)

    def wind(self, t: float, wind_mps: float) -> None:
        """The autopilot's horizontal wind estimate [m/s] (MAVLink WIND_COV / WIND) at t."""
        self.tracker.wind(t, wind_mps)

    def param(self, t: float, name: str, value: float) -> str:
        return self.params.update(t, name, value)

    def restores(self, t: float) -> dict[str, float]:
        """{name: value} to PARAM_SET at t: a parameter set to break a rule, back to its last
        safe value (safety.consistency.ParamGuard.restores)."""
        return self.params.restores(t)

    def handover_ok(self) -> tuple[bool, str]:
        return self.params.handover()

    def handover(self, t: float, observed: FlightMode | None,
                 asked: FlightMode = FlightMode.OFFBOARD) -> None:  # fmt: skip
        """The companion switched the autopilot to `asked` (accepted) at t; from now on the
        camera, if monitored, must deliver (a camera that never did is lost from here)."""
        self.authority.start(t, observed, asked)
        self.tracker.start(t)

    def observe(self, t: float, mode: FlightMode | None, why: str = "") -> str:
        """The autopilot reports `mode` at t (every change, in order): the authority rules."""
        return self.authority.observe(t, mode, why)

    def requested(self, t: float, mode: FlightMode, accepted: bool) -> None:
        self.authority.requested(t, mode, accepted)

    # ---- outputs -----------------------------------------------------------------------------
    def health(self, t: float | None = None) -> Health:
        """The supervisor's input at t — built here and nowhere else."""
        tr = self.tracker
        return Health(tr.camera_t, tr.link_t, self.params.fault, self.params.hold_ok, tr.wind_at(t))

    def certify_column(self, pos_ned: np.ndarray, altitude_m: float) -> tuple[bool, str]:
        """Before a take-off from `pos_ned` (NED about home) to `altitude_m` above home: the
        hand-over point above it must be inside every position row (fence, exclusion zones,
        floor and ceiling), since the autopilot's own take-off flies the column straight up to
        it and the net takes the vehicle there. (ok, reason)."""
        p = np.array([float(pos_ned[0]), float(pos_ned[1]), -float(altitude_m)])
        if not np.isfinite(p).all():
            return False, f"the take-off position {p.tolist()} is not finite"
        if inside_with_margin(self.supervisor.geometry, p, 0.0):
            return True, ""
        lim = self.spec.limits
        return False, (f"the take-off column at {p[0]:.1f} m N, {p[1]:.1f} m E up to "
                       f"{altitude_m:.1f} m is not inside the envelope {self.spec.name!r} (fence, "
                       f"exclusion zones, floor {lim.floor_m:.0f} m, ceiling {lim.ceiling_m:.0f} m)")  # fmt: skip

    def step(self, t: float, state: VehicleState, proposed: Setpoint | None,
             autopilot_mode: FlightMode | None = None, why: str = "") -> Decision:  # fmt: skip
        """One decision at t. `autopilot_mode`: the mode reported now, observed first (a loop
        that observes every change itself passes None). After a yield the decision is still
        computed (and recorded); `request` then asks for nothing."""
        if autopilot_mode is not None:
            self.authority.observe(t, autopilot_mode, why)
        return self.supervisor.update(t, state, proposed, self.health(t))

    def wanted_mode(self, d: Decision) -> FlightMode:
        return autopilot_mode_for(d, self.use_autopilot_hold)

    def request(self, d: Decision) -> FlightMode | None:
        """The mode to ask for now to fly `d`, or None (no authority, or already reported)."""
        return self.authority.request(self.wanted_mode(d))


def _warm_state(t: float, north_m: float) -> VehicleState:
    return VehicleState(t=t, pos_ned=np.array([north_m, 0.0, -100.0]),
                        vel_ned=np.array([20.0, 0.0, 0.0]), quat=np.array([1.0, 0.0, 0.0, 0.0]),
                        omega_frd=np.zeros(3), accel_frd=np.array([0.0, 0.0, -GRAVITY]),
                        on_ground=False)  # fmt: skip


def warm_up(envelope, params) -> float:
    """Build the net's kernels ahead of time when they are not yet (safety.compiled: then the
    process loads neither numba nor its cache), then run a throwaway Supervisor over the same
    envelope through AI, FALLBACK and PID once, so that the kernels load and the recovery's
    nearest point (safety.nearest) is taken before the flight, not inside the MAVLink receive
    thread at the first switch (a stall there, ~1 s wall, is 20 s of vehicle time at 20×).
    Returns the wall time it took [s]."""
    t0 = time.perf_counter()
    ensure_built()
    sv = Supervisor(envelope, params, None)
    for k, north in enumerate((0.0, 5000.0)):  # inside, then far outside the fence
        st = _warm_state(float(k), north)
        sv.update(float(k), st, Setpoint(vel_ned=np.array([20.0, 0.0, 0.0])))
        sv.fallback.engage(st)
        sv.fallback.command(st)
        sv.pid.engage(st)
        sv.pid.command(float(k), st)
    return time.perf_counter() - t0
