"""The companion's view of one vehicle: its MAVLink link, read in ticks on one thread.

Nothing here runs on a thread of its own and nothing reads a clock: time is the tick's, which
is the simulation time of the vehicle's tick mark in lockstep (flight.lockstep) or the
autopilot's own `time_boot_ms` when free-running. Every message from the vehicle is applied
to `Telemetry` in arrival order; in lockstep the link is cut exactly at the tick's mark, and
what arrived after it waits for the next tick, so a decision sees exactly the vehicle's state
up to the frame it was taken on.

The camera's side of it (mission.onboard): `pose_at(t)` is the autopilot's estimate of the
vehicle's pose at a frame's capture time, and `roi_ned` where the vehicle's gimbal was told to
look (`point_gimbal`, as acknowledged).
"""

from __future__ import annotations

import math
import time
from collections import deque
from typing import NamedTuple

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.geo import geodetic_to_ned, ned_to_geodetic
from skyherd.flight.lockstep import NS_PER_US, is_mark
from skyherd.hil.autopilots import UnknownAutopilot
from skyherd.hil.link import MavlinkLink
from skyherd.hil.telemetry import Telemetry, local_setpoint, reposition_command, update_telemetry
from skyherd.perception.camera import UAVPose

M = mavlink2
WIND_MAX_AGE_S = 5.0  # a wind estimate older than this [s] is no estimate (streams at 1 Hz)


ATTITUDES_KEPT = 64  # attitude samples kept for pose_at (6.4 s at 10 Hz)


class Seen(NamedTuple):
    """A change of the autopilot's (mode, armed) in a HEARTBEAT, in arrival order."""

    t: float  # the tick time it arrived in [s] (the latest mark)
    mode: object  # FlightMode or None
    armed: bool
    alt_m: float  # the companion's altitude above home then [m] (NaN before a position)


class LinkLost(Exception):
    """Nothing arrived from the vehicle for longer than the wall-time patience."""


class VehicleLink:
    """One autopilot seen from the companion: telemetry, command acks, status texts."""

    def __init__(self, link: MavlinkLink, target_system: int | None = None):
        self.link = link
        self.target_system = target_system
        self.tel = Telemetry()
        self.acks: dict[int, int] = {}  # MAV_CMD → last MAV_RESULT
        self.t = 0.0  # the current tick's time [s]
        self.heartbeat_t: float | None = None  # tick time of the last autopilot heartbeat [s]
        self.telemetry_t: float | None = None  # tick time of the last position sample [s]
        self.positions: list[tuple[float, np.ndarray, np.ndarray, str, bool]] = []
        self.attitudes: deque[tuple[float, np.ndarray]] = deque(maxlen=ATTITUDES_KEPT)
        self.roi_ned: np.ndarray | None = None  # gimbal ROI as acknowledged (None: nadir)
        self._roi_sent: np.ndarray | None = None  # the last ROI sent, until its ack
        self.setpoint: Setpoint | None = None  # streamed every tick while set (offboard)
        self._held: deque = deque()
        self.params: dict[str, float] = {}  # the autopilot's parameters as read (PARAM_VALUE)
        self.param_count: int | None = None
        self.frame_announced_ms = -1  # lockstep: the tick whose frame the vehicle announced [ms]
        self.param_updates: list[tuple[float, str, float]] = []  # (tick time, name, value), unread
        self._last_mark_ns = -1
        self.unknown_autopilot = ""  # the reason, if the vehicle's autopilot is not one we fly
        self._reposition_t = -float("inf")  # tick time of the last DO_REPOSITION setpoint [s]
        self._outbox: list | None = None  # lockstep: what this tick sends, sent with its close
        self.wind_ned: np.ndarray | None = None  # the autopilot's wind estimate [m/s, NED]
        self.wind_t: float | None = None  # tick time of its last WIND_COV / WIND [s]
        self.seen: list[Seen] = []  # every change of (mode, armed), not sampled per tick

    # ---- receiving ---------------------------------------------------------------------------
    def _pull(self, timeout_s: float) -> bool:
        msgs = self.link.recv(timeout_s)
        self._held.extend(msgs)
        return bool(msgs)

    def next_mark(self, patience_s: float = 30.0) -> float:
        """Lockstep: apply messages up to the vehicle's next tick mark; return its time [s].

        A mark already answered (the vehicle re-sends while it waits) is skipped. Raises
        LinkLost when no mark arrives within `patience_s` of wall time."""
        deadline = time.monotonic() + patience_s
        while True:
            while self._held:
                msg = self._held.popleft()
                if is_mark(msg) and self._from_vehicle(msg):
                    if msg.ts1 <= self._last_mark_ns:
                        continue
                    self._last_mark_ns = msg.ts1
                    self.t = msg.ts1 / (NS_PER_US * 1e6)
                    self._outbox = []
                    return self.t
                self.apply(msg)
            left = deadline - time.monotonic()
            if left <= 0:
                raise LinkLost(f"no tick mark from the vehicle for {patience_s:.0f} s")
            self._pull(min(left, 0.2))

    def hello(self, patience_s: float) -> None:
        """Lockstep: wait for the vehicle's first datagram (a `udpin` link learns the vehicle's
        address from it), then send our first heartbeat: the simulator's clock starts on it."""
        deadline = time.monotonic() + patience_s
        while not self._held:
            if time.monotonic() > deadline:
                raise LinkLost(
                    f"nothing from the vehicle for {patience_s:.0f} s: is `skyherd sim` running?"
                )
            self._pull(0.2)
        self.heartbeat()

    def drain(self, timeout_s: float) -> int:
        """Free-running: apply whatever arrives within `timeout_s` [s of wall time]; the tick
        time follows the autopilot's clock. Returns how many messages arrived."""
        n = 0
        if not self._held:
            self._pull(timeout_s)
        while True:
            while self._held:
                self.apply(self._held.popleft())
                n += 1
            if not self._pull(0.0):
                break
        self.t = self.tel.time_boot_ms / 1000.0
        return n

    def flush(self) -> None:
        """Send what this tick queued, without closing it (the mission ended abnormally)."""
        out, self._outbox = self._outbox, None
        if out:
            self.link.send_many(out)

    def close_tick(self) -> None:
        """Lockstep: send this tick's messages and its close (the TIMESYNC answer) together."""
        out = self._outbox or []
        self._outbox = None
        out.append(self.link.mav.timesync_encode(max(1, self._last_mark_ns), self._last_mark_ns))
        self.link.send_many(out)

    def _from_vehicle(self, msg) -> bool:
        return self.target_system is None or msg.get_srcSystem() == self.target_system

    def apply(self, msg) -> None:
        """One message from the vehicle → Telemetry (decoded per autopilot: hil.telemetry), plus
        what the companion keeps: command acks, heartbeat and position-sample times."""
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        t = msg.get_type()
        if self.target_system is None and t == "HEARTBEAT" and comp == 1:
            self.target_system = src
        if src != self.target_system or (t == "HEARTBEAT" and comp != 1):
            return
        try:
            update_telemetry(self.tel, msg)
        except UnknownAutopilot as e:
            self.unknown_autopilot = str(e)
            return
        if t == "HEARTBEAT":
            self.heartbeat_t = self.t
            tel = self.tel
            if not self.seen or (tel.mode, tel.armed) != self.seen[-1][1:3]:
                alt = -float(tel.pos_ned[2]) if tel.pos_ned is not None else float("nan")
                self.seen.append(Seen(self.t, tel.mode, tel.armed, alt))
        elif t == "LOCAL_POSITION_NED":
            tel = self.tel
            self.telemetry_t = self.t
            self.positions.append((msg.time_boot_ms / 1000.0, tel.pos_ned, tel.vel_ned,
                                   tel.mode.name if tel.mode else "", tel.armed))  # fmt: skip
        elif t == "ATTITUDE_QUATERNION" or (t == "ATTITUDE" and not self.tel.quaternion_seen):
            self.attitudes.append((msg.time_boot_ms / 1000.0, self.tel.quat))
        elif t == "COMMAND_ACK":
            self.acks[msg.command] = msg.result
            if msg.command == M.MAV_CMD_DO_SET_ROI_LOCATION and self._roi_sent is not None:
                if msg.result == M.MAV_RESULT_ACCEPTED:
                    self.roi_ned = self._roi_sent
                self._roi_sent = None
        elif t in ("WIND_COV", "WIND"):
            self._wind(msg)
        elif t == "CAMERA_IMAGE_CAPTURED":  # lockstep: a frame was published for this tick
            self.frame_announced_ms = int(msg.time_boot_ms)
        elif t == "PARAM_VALUE":
            pid = (
                msg.param_id
                if isinstance(msg.param_id, str)
                else msg.param_id.decode("ascii", "replace")
            )
            name = pid.split("\x00", 1)[0]
            self.params[name] = float(msg.param_value)
            self.param_count = int(msg.param_count)
            self.param_updates.append((self.t, name, float(msg.param_value)))

    def pose_at(self, t: float) -> UAVPose | None:
        """The autopilot's estimate of the vehicle's pose at time `t` [s of its clock]: its
        newest position and attitude samples not after t (sample and hold: at most one
        telemetry period old; in lockstep the built-in vehicle streams both at each camera
        instant, before its mark), or the oldest kept when all are after t (the nearest: a
        frame stamped on a clock behind the autopilot's). None until both have arrived, and
        while either is not a number (an EKF without its origin yet: real ArduPlane's first
        LOCAL_POSITION_NED samples; a frame is then used without a camera pose)."""
        pos = _newest_until(self.positions, t)
        att = _newest_until(self.attitudes, t)
        if pos is None or att is None:
            return None
        if not (np.all(np.isfinite(pos[1])) and np.all(np.isfinite(att[1]))):
            return None
        return UAVPose(pos[1], att[1])

    def _wind(self, msg) -> None:
        """PX4's WIND_COV (wind_x, wind_y: the way the air moves, NED) or ArduPilot's WIND
        (direction it comes from [deg], speed) → wind_ned; a non-finite estimate is ignored."""
        if msg.get_type() == "WIND_COV":
            w = np.array([msg.wind_x, msg.wind_y, msg.wind_z], dtype=float)
        else:
            a = math.radians(msg.direction)
            w = np.array([-msg.speed * math.cos(a), -msg.speed * math.sin(a), msg.speed_z])
        if np.all(np.isfinite(w[:2])):
            self.wind_ned, self.wind_t = w, self.t

    def wind_speed(self, max_age_s: float = WIND_MAX_AGE_S) -> float | None:
        """The autopilot's horizontal wind estimate [m/s], or None: none yet, or older than
        max_age_s [s] (the supervisor's Health.wind_mps)."""
        if self.wind_ned is None or self.wind_t is None or self.t - self.wind_t > max_age_s:
            return None
        return float(math.hypot(self.wind_ned[0], self.wind_ned[1]))

    def feed(self, net) -> None:
        """What arrived from this vehicle for its SafetyNet (safety.net), once per tick before
        its step: the link's freshness, anyone's PARAM_SET seen (PARAM_VALUE) and the
        autopilot's wind estimate. A parameter set to break a rule is set back at once
        (`SafetyNet.restores`: PARAM_SET, until its PARAM_VALUE echo agrees)."""
        net.link(self.heartbeat_t, self.telemetry_t)
        for t_p, name, value in self.param_updates:
            net.param(t_p, name, value)
        self.param_updates.clear()
        for name, value in net.restores(self.t).items():
            self.send(M.MAVLink_param_set_message(self.target_system or 1, 1, name.encode("ascii"),
                                                  float(value), M.MAV_PARAM_TYPE_REAL32))  # fmt: skip
        w = self.wind_speed()
        if w is not None:
            net.wind(self.wind_t, w)

    @property
    def home_amsl_m(self) -> float:
        return self.tel.home.alt_m if self.tel.home is not None else 0.0

    @property
    def profile(self):
        return self.tel.profile

    # ---- sending -----------------------------------------------------------------------------
    def send(self, msg) -> None:
        if self._outbox is not None:  # inside a lockstep tick: goes out with its close
            self._outbox.append(msg)
        else:
            self.link.send(msg)

    def heartbeat(self) -> None:
        self.send(M.MAVLink_heartbeat_message(M.MAV_TYPE_ONBOARD_CONTROLLER,
                                              M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3))  # fmt: skip

    def point_gimbal(self, roi_ned: np.ndarray) -> bool:
        """MAV_CMD_DO_SET_ROI_LOCATION to the vehicle's gimbal (MAV_COMP_ID_GIMBAL; the autopilot
        routes it there): look at `roi_ned` (3,) NED about home [m]. It takes effect in `roi_ned`
        when the gimbal acknowledges it. False while home is unknown (nothing sent)."""
        if self.tel.home is None:
            return False
        lat, lon, alt = ned_to_geodetic(self.tel.home, np.asarray(roi_ned, dtype=float))
        self.send(M.MAVLink_command_long_message(self.target_system or 1, M.MAV_COMP_ID_GIMBAL,
                                                 M.MAV_CMD_DO_SET_ROI_LOCATION, 0,
                                                 0, 0, 0, 0, lat, lon, alt))  # fmt: skip
        # where the gimbal will look: params 5-7 travel as float32 (~1 m at this latitude)
        lat, lon, alt = (float(np.float32(x)) for x in (lat, lon, alt))
        self._roi_sent = geodetic_to_ned(self.tel.home, lat, lon, alt)
        return True

    def command_long(self, command: int, params: tuple[float, ...], confirmation: int) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.send(
            M.MAVLink_command_long_message(self.target_system or 1, 1, command, confirmation, *p)
        )

    def position_target(self, pos_ned=None, vel_ned=None, yaw=None, stamp_s: float | None = None):
        """SET_POSITION_TARGET_LOCAL_NED, stamped with the tick's time (the frame it answers);
        DO_REPOSITION at the profile's pace where that is how it takes positions (ArduPlane)."""
        prof = self.profile
        if prof is not None and prof.setpoint_frame == "reposition":
            if pos_ned is None and vel_ned is not None and self.tel.pos_ned is not None:
                pos_ned = self.tel.pos_ned + prof.reposition_lead_s * np.asarray(vel_ned, float)
            if (
                pos_ned is not None
                and self.tel.home is not None
                and (self.t - self._reposition_t >= prof.setpoint_min_interval_s - 1e-9)
            ):
                self._reposition_t = self.t
                self.send(reposition_command(self.tel, prof, self.target_system or 1, pos_ned, yaw))
            return
        stamp = round(1000 * (self.t if stamp_s is None else stamp_s))
        self.send(local_setpoint(self.tel, self.target_system or 1, pos_ned, vel_ned, yaw,
                                 time_ms=stamp))  # fmt: skip


def _newest_until(samples, t: float):
    """The newest sample (a tuple whose first item is its time [s]) not after t; the oldest when
    all are after t; None when there is none."""
    for sample in reversed(samples):
        if sample[0] <= t + 1e-6:
            return sample
    return samples[0] if samples else None
