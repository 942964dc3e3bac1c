"""The safety net beside an autopilot (for `skyherd fly`, the companion and the drills).

    sup = load_net("quadrotor", events=run.events())      # constraint set + supervisor
    auth = Authority(events=run.events())                 # who commands (safety.authority)
    auth.start(t, ap.mode)                                # after the OFFBOARD hand-over
    d = sup.update(t, ap.state, proposal, health)         # health: safety.health.HealthTracker
    apply_decision(ap, d, authority=auth)                 # HOLD or the setpoint, unless yielded

`SafetyNet` bundles the four (supervisor, authority, health tracker, parameter guard) for a
companion that receives MAVLink messages and camera frames: `net.step(...)` → Decision and the
mode to request (None = request nothing).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from flight.autopilot_api import Autopilot, FlightMode, Result, Setpoint
from flight.geo import GRAVITY
from flight.state import VehicleState
from safety.authority import NET_MODES, Authority
from safety.config import default_envelope_path, fill_dataclass, load_envelope
from safety.consistency import ParamGuard
from safety.health import HealthTracker
from safety.supervisor import Decision, EventSink, Health, Mode, Supervisor, SupervisorParams


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


def apply_decision(
    ap: Autopilot, d: Decision, use_autopilot_hold: bool = True, authority: Authority | None = None
) -> Result:
    """FALLBACK → the autopilot's own HOLD (hover / loiter); otherwise stream the command and
    make sure the autopilot is in OFFBOARD — as long as the net has authority.

    With an `authority` (safety.authority) the autopilot's reported mode is observed first; a
    mode the net did not ask for ends the AI's authority and nothing is sent, ever again
    (until someone else gives OFFBOARD back). Without one, the net still never switches away
    from a mode it could not have set (RTL, LAND, a manual mode, MISSION, ...)."""
    t = float(ap.clock.t)
    hold = d.mode is Mode.FALLBACK and use_autopilot_hold and d.autopilot_mode is FlightMode.HOLD
    want = FlightMode.HOLD if hold else FlightMode.OFFBOARD
    if authority is not None:
        authority.observe(t, ap.mode)
        if not authority.has_authority:
            return Result.denied(f"the net has no authority: {authority.reason}")
    elif ap.mode not in NET_MODES:
        return Result.denied(f"the autopilot is in {ap.mode.name}: the net does not override it")
    r = Result.accepted() if hold else ap.set_offboard_setpoint(d.command)
    if not r.ok:
        return r
    ask = authority.request(want) if authority is not None else (want if ap.mode != want else None)
    if ask is None:
        return r
    r = ap.set_mode(ask)
    if authority is not None:
        authority.requested(t, ask, r.ok)
        authority.observe(t, ap.mode)  # in-process the switch is immediate
    return r


class SafetyNet:
    """Supervisor + authority + health + parameter guard for one vehicle (pure; time in).

    Feed it what arrives (`message`, `frame`, `param`) and call `step` once per decision;
    `step` returns the Decision (its `record()` is the decisions.jsonl line) and the mode to
    request now, or None. Before `handover` it commands nothing; `handover_ok()` says whether
    it may (parameters consistent)."""

    def __init__(self, supervisor: Supervisor, events: EventSink | None = None,
                 vehicle: str = "uav0", camera: bool = True):  # fmt: skip
        self.supervisor = supervisor
        self.authority = Authority(events, vehicle)
        self.health = HealthTracker(camera=camera)
        self.params = ParamGuard(supervisor.envelope.spec, supervisor.p.pos_speed_max_mps,
                                 events, vehicle)  # fmt: skip

    def message(self, t: float, msg_type: str) -> None:
        self.health.message(t, msg_type)

    def frame(self, t: float, stamp_t: float | None = None) -> None:
        self.health.frame(t, stamp_t)

    def wind(self, t: float, wind_mps: float) -> None:
        """The autopilot's horizontal wind estimate [m/s] (MAVLink WIND_COV / WIND) at t."""
        self.health.wind(t, wind_mps)

    def param(self, t: float, name: str, value: float) -> str:
        return self.params.update(t, name, value)

    def handover_ok(self) -> tuple[bool, str]:
        return self.params.handover()

    def handover(self, t: float, observed: FlightMode | None) -> None:
        """The companion switched the autopilot to OFFBOARD/GUIDED (accepted) at t."""
        self.authority.start(t, observed)

    def step(self, t: float, state: VehicleState, proposed: Setpoint | None,
             autopilot_mode: FlightMode | None, why: str = "") -> tuple[Decision, FlightMode | None]:  # fmt: skip
        """One decision at t: (decision, mode to request or None). After a yield the decision
        is still computed (and recorded) but nothing is to be sent."""
        self.authority.observe(t, autopilot_mode, why)
        h = self.health.health(t)
        h = Health(h.camera_t, h.link_t, self.params.fault, self.params.hold_ok, h.wind_mps)
        d = self.supervisor.update(t, state, proposed, h)
        if not self.authority.has_authority:
            return d, None
        return d, self.authority.request(d.autopilot_mode)

    def requested(self, t: float, mode: FlightMode, accepted: bool) -> None:
        self.authority.requested(t, mode, accepted)


def warm_up(envelope, params) -> float:
    """Run a throwaway Supervisor over the same envelope through AI, FALLBACK and PID once, so
    that the numba kernels load and the recovery QP is built before the flight, not inside
    the MAVLink receive thread at the first switch (a stall there, ~1 s wall, is 20 s of vehicle
    time at 20×). Returns the wall time it took [s]."""
    t0 = time.perf_counter()
    sv = Supervisor(envelope, params, None)
    for k, north in enumerate((0.0, 5000.0)):  # inside, then far outside the fence
        st = VehicleState(t=float(k), pos_ned=np.array([north, 0.0, -100.0]),
                vel_ned=np.array([20.0, 0.0, 0.0]), quat=np.array([1.0, 0.0, 0.0, 0.0]),
                omega_frd=np.zeros(3), accel_frd=np.array([0.0, 0.0, -GRAVITY]), on_ground=False)  # fmt: skip
        sv.update(float(k), st, Setpoint(vel_ned=np.array([20.0, 0.0, 0.0])), Health())
        sv.fallback.engage(st)
        sv.fallback.command(st)
        sv.pid.engage(st)
        sv.pid.command(float(k), st)
    return time.perf_counter() - t0
