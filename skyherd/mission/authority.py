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
A request refused *for now* (COMMAND_ACK TEMPORARILY_REJECTED) is the autopilot's own failsafe
in force: the net yields at once (`Authority.refused`) and never retries over it. This closes
the crossing the campaign found (docs/safety.md, Run 7): a request decided on the tick the
autopilot's battery failsafe switched arrives the lockstep latency later, before any heartbeat
could show the switch; the autopilot refuses it instead of being switched out of its failsafe,
and the heartbeat that then shows the failsafe's mode is written as not the companion's.
Blind — no telemetry for longer than `blind_s` or no heartbeat for longer than
`heartbeat_blind_s` (a lost link), and then until a heartbeat newer than the gap's start has
come — nothing is asked: the companion does not know the mode the autopilot chose meanwhile
(its offboard-loss HOLD, a battery RTL), and a request sent into the cut would arrive when the
link is back and undo that failsafe before its heartbeat told of it. That first heartbeat is
judged as a change (`Authority.resync`): a mode other than the one asked for is the
autopilot's, even if the last heartbeat before the gap showed it too (found by the campaign
through the mission code, `skyherd drill --campaign`: link_loss and param_sabotage drills,
whose cut is real).

Every change of (mode, armed) the vehicle's heartbeats show (`VehicleLink.seen`, in arrival
order, not sampled per tick) is fed to the rules, so an RTL that comes and goes between two
ticks still ends the AI's authority, and is written to modes.jsonl (`log`): t, mode, armed,
alt_m, by_companion (true / false while the net has the vehicle; null before the hand-over and
after the AI phase, when the take-off and landing steps own the modes), authority (the rules'
phase). A disarm in the air while the net has the vehicle ends the mission as failed.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode
from skyherd.mission.steps import MissionError, mode_params
from skyherd.mission.vehicle import Seen, VehicleLink
from skyherd.safety.authority import Authority

M = mavlink2


@dataclass
class ModeAuthority:
    rules: Authority = field(default_factory=Authority)  # the net's (SafetyNet.authority)
    retry_s: float = 1.0  # re-send a request not yet shown after this long [s]
    pending: FlightMode | None = None  # the request sent and not yet answered
    t_sent: float = -1e9
    requests: int = 0
    log: object | None = None  # modes.jsonl (a runio.JsonlWriter) or None
    airborne_m: float = 0.5  # a disarm above this altitude [m] is a disarm in the air
    t_start: float | None = None  # tick time of the hand-over [s]
    t_last: float | None = None  # tick time of the last update under the rules [s]
    blind_s: float = 0.5  # no telemetry for longer than this: blind [s] (it streams >= 10 Hz)
    heartbeat_blind_s: float = 1.5  # no heartbeat for longer than this: blind [s] (1 Hz + margin)
    blind_since: float | None = None  # tick time the gap was found; None: not blind [s]
    refused_unseen: bool = False  # yielded on a refusal; the failsafe's heartbeat not yet seen
    _read: int = 0  # how many of VehicleLink.seen are taken

    def adopt(self, v: VehicleLink, mode: FlightMode) -> None:
        """The hand-over: a phase put the vehicle in `mode`; the net now has it."""
        self.record(v)
        self.rules.start(v.t, v.tel.mode, mode)
        self.t_start = self.t_last = v.t

    def record(self, v: VehicleLink) -> None:
        """Write the changes seen since the last call, outside the rules (take-off, landing)."""
        self._take(v, feed=False)

    def _take(self, v: VehicleLink, feed: bool) -> None:
        new = v.seen[self._read :]
        self._read = len(v.seen)
        for s in new:
            by = None
            if feed and (self.rules.has_authority or self.refused_unseen):
                by = s.mode is self.rules.asked and s.armed and not self.refused_unseen
                self.refused_unseen = False
                if not s.armed and s.alt_m > self.airborne_m:
                    self._write(s, by)
                    raise MissionError(f"disarmed in the air at {s.alt_m:.1f} m (t = {s.t:.2f} s)"
                                       f": not by the companion; the vehicle falls")  # fmt: skip
            if feed:
                self.rules.observe(s.t, s.mode, v.tel.statustext)
            self._write(s, by)

    def _write(self, s: Seen, by: bool | None) -> None:
        if self.log is None:
            return
        rec = {"t": round(s.t, 6), "mode": s.mode.name if s.mode else None, "armed": s.armed,
               "alt_m": None if s.alt_m != s.alt_m else round(s.alt_m, 3), "by_companion": by,
               "authority": self.rules.phase.value}  # fmt: skip
        try:
            self.log.write(rec)
        except Exception:  # noqa: BLE001  the record never stops the flight
            pass

    def update(self, v: VehicleLink) -> str:
        """Once per tick: the autopilot's answer to a pending request, then its reported mode.
        Returns "fly", "wait" or "end" (safety.authority's rule 2). A refusal for now is judged
        after the changes seen: a heartbeat that already shows the failsafe names the yield."""
        refused = None
        if self.pending is not None:
            result = v.acks.get(M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_IN_PROGRESS)
            if result != M.MAV_RESULT_IN_PROGRESS:
                v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
                if result == M.MAV_RESULT_TEMPORARILY_REJECTED:
                    refused = self.pending
                elif result != M.MAV_RESULT_ACCEPTED:
                    self.rules.requested(v.t, self.pending, accepted=False)
                self.pending = None
        if self.t_start is None:  # the first tick under the rules: the hand-over's (a net's
            self.record(v)  # `handover` started the rules); what came before it is the phases'
            self.t_start = v.t
        self._take(v, feed=True)  # every change in arrival order, not the tick's last
        if refused is not None:
            self.refused_unseen = bool(self.rules.refused(v.t, refused, v.tel.statustext))
        if self.gap(v):
            if self.blind_since is None:
                self.blind_since = v.t
        elif self.blind_since is not None and (v.heartbeat_t or -1.0) > self.blind_since:
            self.blind_since = None  # a heartbeat after the gap: its mode, judged anew
            self.rules.resync(v.t, v.tel.mode, v.tel.statustext)
        self.t_last = v.t
        return self.rules.mission

    @property
    def yielded(self) -> str | None:
        """Why the autopilot has the vehicle (None while the net has it)."""
        return None if self.rules.has_authority or not self.rules.reason else self.rules.reason

    def gap(self, v: VehicleLink) -> bool:
        """Telemetry or heartbeats missing for longer than they may be (or none yet)."""
        return (v.telemetry_t is None or v.t - v.telemetry_t > self.blind_s
                or v.heartbeat_t is None or v.t - v.heartbeat_t > self.heartbeat_blind_s)  # fmt: skip

    def want(self, v: VehicleLink, mode: FlightMode) -> None:
        """Request `mode` unless the rules forbid it, it is shown, or it was sent recently."""
        ask = self.rules.request(mode)
        if ask is None or (ask is self.pending and v.t - self.t_sent < self.retry_s):
            return
        if self.blind_since is not None or self.gap(v):
            return  # blind: the autopilot may have chosen a mode we have not seen (docstring)
        self.rules.requested(v.t, ask, accepted=True)  # the switch may show before the ACK
        v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
        v.command_long(M.MAV_CMD_DO_SET_MODE, mode_params(v, ask), 0)
        self.pending, self.t_sent = ask, v.t
        self.requests += 1
