"""Telemetry stream scheduling on simulation time, with per-message rates per link.

Default rates: the API link's (`DEFAULT_RATES_HZ`, what the companion's flights are tuned on)
and the ground-station link's (`GCS_RATES_HZ`, PX4's normal mode). SET_MESSAGE_INTERVAL changes
one message's rate on the link that asked (as PX4 does); interval -1 stops it, 0 restores the
link's default.
"""

from __future__ import annotations

import math
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

# message id → default rate [Hz] (0 = not streamed unless asked for).
DEFAULT_RATES_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 20.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 10.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 10.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_ALTITUDE: 10.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 4.0,
    mavlink.MAVLINK_MSG_ID_MISSION_CURRENT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: 0.0,
    # the autopilot's wind estimate (PX4: WIND_COV, ArduPilot: WIND); only the one the
    # personality sends, and only for an autopilot that estimates wind (the endpoint drops
    # what its TelemetryBuilder cannot build)
    mavlink.MAVLINK_MSG_ID_WIND_COV: 1.0,
    mavlink.MAVLINK_MSG_ID_WIND: 1.0,
}
# The ground-station link: PX4's MAVLINK_MODE_NORMAL rates (mavlink_main.cpp,
# configure_streams_to_default) for the messages above; MISSION_CURRENT as on the API link.
GCS_RATES_HZ: dict[int, float] = {
    **DEFAULT_RATES_HZ,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 15.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 1.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,
    mavlink.MAVLINK_MSG_ID_ALTITUDE: 1.0,
}
MAX_RATE_HZ = 500.0  # faster requests are clamped


class StreamScheduler:
    """Which messages are due on one link at simulation time t [s]."""

    def __init__(self, defaults: dict[int, float] | None = None,
                 on_change: Callable[[], None] | None = None):  # fmt: skip
        self._on_change = on_change  # called when a rate changes (the endpoint's due time)
        self.defaults = dict(DEFAULT_RATES_HZ if defaults is None else defaults)
        self.rates: dict[int, float] = dict(self.defaults)
        self._next: dict[int, float] = {}
        self.next_due = -1.0  # no message is due before this time [s] (-1: recompute at once)
        self.held_back = 0  # sends skipped while nobody listened (`due(t, only=...)`)
        self._periods: list[tuple[int, float]] = []  # (msg id, period [s]) of streamed messages
        self._changed()

    def _changed(self) -> None:
        self._periods = [(m, 1.0 / r) for m, r in self.rates.items() if r > 0]
        self.next_due = -1.0
        if self._on_change is not None:
            self._on_change()

    def drop(self, msg_id: int) -> None:
        """This link cannot stream msg_id (its autopilot does not provide it)."""
        self.defaults.pop(msg_id, None)
        self.rates.pop(msg_id, None)
        self._next.pop(msg_id, None)
        self._changed()

    def supports(self, msg_id: int) -> bool:
        return msg_id in self.defaults

    def set_interval(self, msg_id: int, interval_us: float) -> bool:
        """SET_MESSAGE_INTERVAL semantics. False if the message cannot be streamed or the
        interval is not a number."""
        if not self.supports(msg_id) or not math.isfinite(interval_us):
            return False
        if interval_us == -1:
            rate = 0.0
        elif interval_us == 0:
            rate = self.defaults[msg_id]
        elif interval_us > 0:
            rate = min(1e6 / interval_us, MAX_RATE_HZ)
        else:
            return False
        self.rates[msg_id] = rate
        self._next.pop(msg_id, None)
        self._changed()
        return True

    def interval_us(self, msg_id: int) -> int:
        """MESSAGE_INTERVAL answer: -1 stopped, 0 not available, else the interval [us]."""
        if not self.supports(msg_id):
            return 0
        rate = self.rates[msg_id]
        return -1 if rate <= 0 else int(round(1e6 / rate))

    def due(self, t: float, only: int | None = None) -> list[int]:
        """Message ids to send now; each is rescheduled one period later (no catch-up bursts).

        `only`: the link is heard by nobody, only this message goes out (the heartbeat that
        finds the next listener). The others are not woken for: when this one is due, each is
        moved past t and the sends it missed are counted in `held_back`; the step after this
        one is sent, the link is looked at again (so streams resume one step after a heartbeat
        is no longer refused)."""
        if t < self.next_due - 1e-9:
            return []  # the common case, checked once per step
        out = []
        nexts = self._next
        for msg_id, period in self._periods:
            nxt = nexts.get(msg_id)
            if nxt is None:
                nexts[msg_id] = t + period
            elif t >= nxt - 1e-9:
                if only is not None and msg_id != only:  # every instant it missed up to t
                    n = math.floor((t - nxt + 1e-9) / period) + 1
                    nexts[msg_id] = nxt + n * period
                    self.held_back += n
                    continue
                nxt += period
                nexts[msg_id] = nxt if nxt > t else t + period  # fell behind: skip, no burst
            else:
                continue
            out.append(msg_id)
        # _next holds only streamed messages (set_interval drops the others).
        if only is None:
            self.next_due = min(nexts.values(), default=math.inf)
        elif only in out:
            self.next_due = t  # look again at the next step: is anybody there now?
        else:
            self.next_due = nexts.get(only, math.inf)
        return out
