"""The one place that maps the safety net's decision onto the autopilot's modes, and the rule
by which the companion yields to the autopilot.

The net's decision names the mode the vehicle should fly in: the AI's (OFFBOARD; GUIDED on
ArduPilot) or the fallback (the autopilot's own position hold: PX4 Hold, ArduCopter BRAKE,
ArduPlane LOITER). `Authority.want(mode)` requests it (DO_SET_MODE, re-sent every `retry_s`
until the heartbeat shows it) without blocking the tick.

Yielding (never undo an autopilot's failsafe): the companion may only see the vehicle in the
mode it requested last, or in the mode it was in before that request while the request is
being answered. Any other mode — a battery or link-loss failsafe (RTL, LAND), a fence action,
a ground station or an RC pilot — means the autopilot has taken over: `yielded` gets the reason,
and from then on the companion requests no mode and streams no setpoint. The mission ends
and waits for the vehicle to land under the autopilot's control.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode
from mission.steps import mode_params
from mission.vehicle import VehicleLink

M = mavlink2


@dataclass
class Authority:
    retry_s: float = 1.0  # re-send a mode request not yet shown after this long [s]
    requested: FlightMode | None = None
    previous: FlightMode | None = None  # the mode before the pending request
    t_request: float = -1e9
    yielded: str | None = None  # why the autopilot has the vehicle now (None: we have it)
    requests: int = 0

    def adopt(self, mode: FlightMode) -> None:
        """The mode the companion reached by a phase (hand-over): it now holds authority."""
        self.requested, self.previous = mode, None

    def check(self, v: VehicleLink) -> str | None:
        """Call once per tick before deciding; returns the reason when the autopilot took over."""
        mode = v.tel.mode
        if self.yielded is not None or self.requested is None or mode is None:
            return self.yielded
        if mode is self.requested:
            self.previous = None  # the request is done
            return None
        if mode is self.previous:
            return None  # still being answered
        self.yielded = (
            f"the autopilot switched to {mode.name} at t = {v.t:.1f} s (the companion had asked "
            f"for {self.requested.name}): its failsafe, a ground station or a pilot has the vehicle"
        )
        return self.yielded

    def want(self, v: VehicleLink, mode: FlightMode) -> None:
        """Request `mode` unless it is shown, already requested recently, or we have yielded."""
        if self.yielded is not None:
            return
        if v.tel.mode is mode and self.requested is mode:
            return
        if self.requested is not mode:
            self.previous, self.requested = v.tel.mode, mode
        elif v.t - self.t_request < self.retry_s:
            return
        self.t_request = v.t
        self.requests += 1
        v.command_long(M.MAV_CMD_DO_SET_MODE, mode_params(v, mode), 0)
