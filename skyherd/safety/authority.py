"""Who commands the vehicle: the net yields to the autopilot (a pure, time-passed-in machine).

The companion hands the vehicle to the AI by switching the autopilot to OFFBOARD (PX4) or
GUIDED (ArduPilot). From then on it may itself ask for two modes only: OFFBOARD (AI and the
recovery PID) and HOLD (the fallback). Any *change* of the autopilot's reported mode that the
net did not ask for — the autopilot's own failsafe (battery, link loss, fence, GPS), a ground
station, an RC pilot — ends the AI's authority:

    rule 1  the net never again requests OFFBOARD/GUIDED or HOLD by itself and stops streaming
            setpoints; the switch is written to events.jsonl with the mode and the reason;
    rule 2  the mission ENDS when the new mode is RTL or LAND (a failsafe that brings the
            vehicle down or home is never undone); it WAITS for any other mode (HOLD, POSCTL,
            MISSION, ...): the companion keeps perceiving and recording but commands nothing;
    rule 3  authority comes back only when someone else puts the autopilot back in OFFBOARD
            (the heartbeat shows OFFBOARD although the net did not ask): the AI resumes, the
            event says so. A mission that ENDED never resumes.

"Asked for" means: the net sent the request and the autopilot accepted it (COMMAND_ACK
accepted, or `Result.ok` in-process). A mode the net asked for but that was denied counts as
not asked for. The reported mode that has not changed yet (heartbeats lag the request) is
not a change, so a stale heartbeat never ends authority.

A request the autopilot refuses *for now* (COMMAND_ACK TEMPORARILY_REJECTED: its own failsafe
is in force, flight.autopilot_api.AutopilotBase) is the autopilot having taken over, whatever
its heartbeat shows yet (`refused`): rules 1 and 2 as for a change; the request is never
retried over the failsafe.
"""

from __future__ import annotations

import enum
from typing import Any

from skyherd.flight.autopilot_api import FlightMode

NET_MODES = (FlightMode.OFFBOARD, FlightMode.HOLD)
ENDING_MODES = (FlightMode.RTL, FlightMode.LAND)
NOT_SHOWN = "?"  # the mode of a yield on a refusal, until a heartbeat shows it


class Phase(enum.Enum):
    BEFORE = "before hand-over"  # the net has not taken the vehicle yet
    AI = "ai"  # the net (AI, fallback, PID) commands the vehicle
    WAIT = "wait"  # yielded; the mission waits for someone to give OFFBOARD back
    ENDED = "ended"  # yielded to RTL / LAND; the mission is over


class Authority:
    """Tracks the autopilot's reported mode against the net's accepted requests."""

    def __init__(self, events=None, vehicle: str = "uav0"):
        self.events = events
        self.vehicle = vehicle
        self.phase = Phase.BEFORE
        self.observed: FlightMode | None = None
        self.asked: FlightMode | None = None  # last request the autopilot accepted
        self.asked_t: float | None = None
        self._before: FlightMode | None = None  # the request before the last one
        self.reason = ""
        self.yields: list[tuple[float, str, str]] = []  # (t, mode, reason)

    # ---- inputs ------------------------------------------------------------------------
    def start(
        self, t: float, observed: FlightMode | None, asked: FlightMode = FlightMode.OFFBOARD
    ) -> None:
        """The hand-over: the net asked for `asked` (accepted) at t; the autopilot reports
        `observed`."""
        self.phase = Phase.AI
        self.asked, self.asked_t = asked, t
        self.observed = observed
        self._event(t, "handover", observed, f"net takes the vehicle in {asked.name}")

    def requested(self, t: float, mode: FlightMode, accepted: bool) -> None:
        """The net asked the autopilot for `mode` at t; `accepted`: the autopilot's answer.
        A companion whose answer arrives on another thread than the heartbeats calls it with
        True *before* sending (the switch may show before the ACK) and again with False if the
        request is then refused: the earlier request is restored."""
        if mode not in NET_MODES:
            return
        if accepted:
            if mode is not self.asked:
                self._before = self.asked
            self.asked, self.asked_t = mode, t
        elif mode is self.asked and self._before is not None:
            self.asked, self._before = self._before, None

    def observe(self, t: float, mode: FlightMode | None, why: str = "") -> str:
        """The autopilot reports `mode` at t (heartbeat). Returns the reason if this ended
        the AI's authority now, else "". `why`: e.g. the autopilot's latest STATUSTEXT."""
        if mode is None:
            return ""
        prev, self.observed = self.observed, mode
        if mode is prev:
            return ""  # no change: a stale heartbeat or a denied request, never a yield
        if self.phase is Phase.AI and mode is not self.asked:
            reason = f"the autopilot switched {prev.name if prev else '?'} -> {mode.name}, not asked for by the net"
            return self._yield(t, mode, reason + (f" ({why})" if why else ""))
        if self.phase is not Phase.AI and self.yields and self.yields[-1][1] == NOT_SHOWN:
            ty, _, why_y = self.yields[-1]  # a refusal's yield: named by the mode now shown
            self.yields[-1] = (ty, mode.name, why_y)
        if self.phase is Phase.WAIT and mode is FlightMode.OFFBOARD:
            self.phase = Phase.AI
            self.asked, self.asked_t = mode, t
            self._event(t, "regain", mode, "OFFBOARD given back by someone else: the AI resumes")
        elif self.phase is Phase.WAIT and mode in ENDING_MODES:
            self.phase = Phase.ENDED
            self._event(t, "end", mode, f"{mode.name} while waiting: mission ends")
        return ""

    def refused(self, t: float, mode: FlightMode, why: str = "") -> str:
        """The autopilot refused the net's request for `mode` at t for now: its own failsafe
        holds the vehicle. The net yields (WAIT, or ENDED if the mode shown is RTL / LAND; a
        later RTL / LAND ends a WAIT, `observe`). Returns the reason if this ended the AI's
        authority now, else "" (it had already ended)."""
        self.requested(t, mode, accepted=False)
        if self.phase is not Phase.AI:
            return ""
        reason = f"the autopilot refused {mode.name}: its own failsafe is in force"
        return self._yield(t, None, reason + (f" ({why})" if why else ""))

    def _yield(self, t: float, mode: FlightMode | None, reason: str) -> str:
        """The AI's authority ends at t (rules 1 and 2); `mode`: the one shown then (None: not
        shown yet, a refusal's; the next mode shown names the yield, `observe`)."""
        self.phase = Phase.ENDED if mode in ENDING_MODES else Phase.WAIT
        ended = self.phase is Phase.ENDED
        rule = "mission ends" if ended else "mission waits for OFFBOARD from the operator"
        self.reason = f"{reason}; {rule}"
        self.yields.append((t, mode.name if mode else NOT_SHOWN, self.reason))
        self._event(t, "yield", mode, self.reason)
        return self.reason

    def resync(self, t: float, mode: FlightMode | None, why: str = "") -> str:
        """After a gap in the heartbeats (a lost link): the mode shown now is judged as if it
        had just changed — a change during the gap was not seen, and a mode other than the
        one asked for is the autopilot's (observe's rules). Returns what `observe` returns."""
        self.observed = None
        return self.observe(t, mode, why)

    # ---- outputs -----------------------------------------------------------------------
    @property
    def has_authority(self) -> bool:
        return self.phase is Phase.AI

    @property
    def mission(self) -> str:
        """ "fly" | "wait" | "end" (rule 2) — "fly" also before the hand-over."""
        return {Phase.WAIT: "wait", Phase.ENDED: "end"}.get(self.phase, "fly")

    def request(self, want: FlightMode) -> FlightMode | None:
        """The mode the net should ask for now to fly `want` (HOLD or OFFBOARD), or None: it
        may not (yielded), or the autopilot already reports it."""
        if self.phase is not Phase.AI or want not in NET_MODES or self.observed is want:
            return None
        return want

    def _event(self, t: float, kind: str, mode: FlightMode | None, reason: str) -> None:
        if self.events is None:
            return
        rec: dict[str, Any] = {
            "t": round(float(t), 6),
            "event": kind,
            "vehicle": self.vehicle,
            "autopilot_mode": mode.name if mode is not None else None,
            "phase": self.phase.value,
            "reason": reason,
        }
        try:
            self.events.write(rec)
        except Exception:  # noqa: BLE001  logging never stops the safety net
            pass
