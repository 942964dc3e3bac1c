"""The safety net beside an autopilot, in two calls (for `skyherd fly` and the drills).

net = load_net("quadrotor", events=run.events())          # constraint set + supervisor
d = net.update(t, ap.state, proposal, Health(camera_t, link_t))
apply_decision(ap, d)                                     # HOLD or the offboard setpoint
"""

from __future__ import annotations

from pathlib import Path

from flight.autopilot_api import Autopilot, FlightMode, Result
from safety.config import default_envelope_path, fill_dataclass, load_envelope
from safety.supervisor import Decision, EventSink, Mode, Supervisor, SupervisorParams


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
