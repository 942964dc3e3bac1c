"""The one place that maps the safety net's decision onto the autopilot's modes, over MAVLink.

The net (safety.net.SafetyNet) decides the mode the vehicle should fly in: the AI's (OFFBOARD;
GUIDED on ArduPilot) or the fallback (the autopilot's own position hold: PX4 Hold, ArduCopter
BRAKE, ArduPlane LOITER). `ModeAuthority.want(v, mode)` carries that request over MAVLink with
DO_SET_MODE (the profile's numbers), re-sent every `retry_s` until the heartbeat shows it,
without blocking the tick; it maps nothing itself.

Whether the companion may ask at all is decided by `safety.authority.Authority` (a pure,
time-passed-in machine; its rules in its docstring): a mode the net did not ask for (a battery
or link-loss failsafe, a fence action, a ground station, an RC pilot) ends the AI's authority;
the mission ends on RTL / LAND and waits on any other mode until someone gives OFFBOARD back.
A request counts as asked for when it is sent, and is withdrawn if the autopilot refuses it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode
from mission.steps import mode_params
from mission.vehicle import VehicleLink
from safety.authority import Authority

M = mavlink2


@dataclass
class ModeAuthority:
    rules: Authority = field(default_factory=Authority)  # the net's (SafetyNet.authority)
    retry_s: float = 1.0  # re-send a request not yet shown after this long [s]
    pending: FlightMode | None = None  # the request sent and not yet answered
    t_sent: float = -1e9
    requests: int = 0

    def adopt(self, v: VehicleLink, mode: FlightMode) -> None:
        """The hand-over: a phase put the vehicle in `mode`; the net now has it."""
        self.rules.start(v.t, v.tel.mode, mode)

    def update(self, v: VehicleLink) -> str:
        """Once per tick: the autopilot's answer to a pending request, then its reported mode.
        Returns "fly", "wait" or "end" (safety.authority's rule 2)."""
        if self.pending is not None:
            result = v.acks.get(M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_IN_PROGRESS)
            if result != M.MAV_RESULT_IN_PROGRESS:
                v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
                if result != M.MAV_RESULT_ACCEPTED:
                    self.rules.requested(v.t, self.pending, accepted=False)
                self.pending = None
        self.rules.observe(v.t, v.tel.mode, v.tel.statustext)
        return self.rules.mission

    @property
    def yielded(self) -> str | None:
        """Why the autopilot has the vehicle (None while the net has it)."""
        return None if self.rules.has_authority or not self.rules.reason else self.rules.reason

    def want(self, v: VehicleLink, mode: FlightMode) -> None:
        """Request `mode` unless the rules forbid it, it is shown, or it was sent recently."""
        ask = self.rules.request(mode)
        if ask is None or (ask is self.pending and v.t - self.t_sent < self.retry_s):
            return
        self.rules.requested(v.t, ask, accepted=True)  # the switch may show before the ACK
        v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
        v.command_long(M.MAV_CMD_DO_SET_MODE, mode_params(v, ask), 0)
        self.pending, self.t_sent = ask, v.t
        self.requests += 1
