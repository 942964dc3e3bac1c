"""The safety net beside an autopilot, in two calls (for `skyherd fly` and the drills).

net = load_net("quadrotor", events=run.events())          # constraint set + supervisor
d = net.update(t, ap.state, proposal, Health(camera_t, link_t))
apply_decision(ap, d)                                     # HOLD or the offboard setpoint
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from flight.autopilot_api import Autopilot, FlightMode, Result, Setpoint
from flight.geo import GRAVITY
from flight.state import VehicleState
from safety.config import default_envelope_path, fill_dataclass, load_envelope
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


def apply_decision(ap: Autopilot, d: Decision, use_autopilot_hold: bool = True) -> Result:
    """FALLBACK → the autopilot's own HOLD (hover / loiter); otherwise stream the command and
    make sure the autopilot is in OFFBOARD."""
    if d.mode is Mode.FALLBACK and use_autopilot_hold:
        return ap.set_mode(FlightMode.HOLD) if ap.mode != FlightMode.HOLD else Result.accepted()
    r = ap.set_offboard_setpoint(d.command)
    if r.ok and ap.mode != FlightMode.OFFBOARD:
        r = ap.set_mode(FlightMode.OFFBOARD)
    return r


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
