"""Link and camera health from what actually arrives, for the supervisor's `Health` input.

The companion feeds every MAVLink message and every camera frame it receives, with the
simulation time of its arrival (the companion's clock, never wall time):

    tracker = HealthTracker()
    tracker.message(t, "HEARTBEAT")            # receive thread, per message
    tracker.frame(t, stamp_t=frame.t)          # per frame taken from the Zenoh stream
    tracker.wind(t, wind_mps)                  # per WIND_COV / WIND (the autopilot's estimate)
    camera_t, link_t = tracker.camera_t, tracker.link_t    # safety.net.SafetyNet builds Health
    wind_mps = tracker.wind_at(t)

Link: the link is as fresh as the *older* of the newest heartbeat and the newest position
telemetry (LOCAL_POSITION_NED or ODOMETRY): heartbeats without telemetry leave the net flying
on a stale state, telemetry without heartbeats means the autopilot may no longer hear us
either (the heartbeat is the autopilot's "I am alive" that PX4 and ArduPilot both send at
1 Hz or more). Before the first of either arrived, link_t is None (not monitored yet).

Camera: the newest frame whose capture stamp is at most `max_frame_age_s` older than its
arrival; a frame that arrives late (a stuck or slow stream) does not make the camera healthy.

Non-finite times and times that go backwards are ignored and counted in `rejected`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

TELEMETRY = frozenset({"LOCAL_POSITION_NED", "ODOMETRY", "GLOBAL_POSITION_INT"})


@dataclass(frozen=True)
class HealthParams:
    max_frame_age_s: float = 0.5  # a frame captured longer before its arrival is stale [s]
    max_wind_age_s: float = 5.0  # a wind estimate older than this is no estimate [s]
    require_telemetry: bool = True  # the link needs position telemetry as well as heartbeats

    def __post_init__(self) -> None:
        if not self.max_frame_age_s > 0:
            raise ValueError(f"health.max_frame_age_s must be > 0, got {self.max_frame_age_s}")


class HealthTracker:
    """Arrival times → the camera's and the link's freshness (`camera_t`, `link_t`), which
    safety.net.SafetyNet puts into the supervisor's Health. One per vehicle; not thread-safe (the
    caller serialises, e.g. under the companion's lock)."""

    def __init__(self, params: HealthParams = HealthParams(), camera: bool = True):
        self.p = params
        self.camera = camera
        self.heartbeat_t: float | None = None
        self.telemetry_t: float | None = None
        self.frame_t: float | None = None
        self.wind_mps: float | None = None  # the autopilot's horizontal wind estimate [m/s]
        self.wind_t: float | None = None
        self.first_t: float | None = None
        self.start_t: float | None = None  # the hand-over: the camera must deliver from here
        self.messages = 0
        self.frames = 0
        self.stale_frames = 0
        self.rejected = 0

    @staticmethod
    def _newer(old: float | None, t: float) -> bool:
        return math.isfinite(t) and (old is None or t >= old)

    def message(self, t: float, msg_type: str = "HEARTBEAT") -> None:
        """A MAVLink message of `msg_type` arrived at simulation time t [s]."""
        try:
            t = float(t)
        except (TypeError, ValueError):
            self.rejected += 1
            return
        if msg_type == "HEARTBEAT":
            if not self._newer(self.heartbeat_t, t):
                self.rejected += 1
                return
            self.heartbeat_t = t
        elif msg_type in TELEMETRY:
            if not self._newer(self.telemetry_t, t):
                self.rejected += 1
                return
            self.telemetry_t = t
        else:
            return
        if self.first_t is None:
            self.first_t = t
        self.messages += 1

    def start(self, t: float) -> None:
        """The AI takes the vehicle at t [s]: a camera that has not delivered a frame yet counts
        as lost from here (before, from the first message)."""
        if self.start_t is None and math.isfinite(t):
            self.start_t = float(t)

    def frame(self, t: float, stamp_t: float | None = None) -> None:
        """A camera frame arrived at t [s]; stamp_t: its capture time [s] (None: = t)."""
        try:
            t = float(t)
            stamp = t if stamp_t is None else float(stamp_t)
        except (TypeError, ValueError):
            self.rejected += 1
            return
        if not (self._newer(self.frame_t, t) and math.isfinite(stamp)):
            self.rejected += 1
            return
        if t - stamp > self.p.max_frame_age_s:
            self.stale_frames += 1
            return
        self.frame_t = t
        self.frames += 1

    def wind(self, t: float, wind_mps: float) -> None:
        """The autopilot's horizontal wind estimate [m/s] (WIND_COV / WIND) arrived at t [s]."""
        try:
            t, w = float(t), float(wind_mps)
        except (TypeError, ValueError):
            self.rejected += 1
            return
        if not (self._newer(self.wind_t, t) and math.isfinite(w) and w >= 0):
            self.rejected += 1
            return
        self.wind_t, self.wind_mps = t, w

    @property
    def link_t(self) -> float | None:
        """The link's freshness [s]: min(newest heartbeat, newest telemetry); when one of the
        two never arrived, the first arrival of the other (lost after the timeout)."""
        hb, tel = self.heartbeat_t, self.telemetry_t
        if not self.p.require_telemetry:
            return hb
        if hb is None and tel is None:
            return None
        if hb is None or tel is None:
            return self.first_t
        return min(hb, tel)

    @property
    def camera_t(self) -> float | None:
        """The camera's freshness [s]; None when the camera is not monitored. Before the first
        frame the camera counts as lost from the hand-over (`start`), or before it from the
        first message on: a camera that never delivered is lost, not unmonitored."""
        if not self.camera:
            return None
        if self.frame_t is not None:
            return self.frame_t
        return self.start_t if self.start_t is not None else self.first_t

    def wind_at(self, t: float | None = None) -> float | None:
        """The autopilot's wind estimate [m/s] at t [s]; None: none yet, or older than
        max_wind_age_s."""
        if t is not None and self.wind_t is not None and t - self.wind_t > self.p.max_wind_age_s:
            return None  # stale: no estimate
        return self.wind_mps
