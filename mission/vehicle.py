"""The companion's view of one vehicle: its MAVLink link, read in ticks on one thread.

Nothing here runs on a thread of its own and nothing reads a clock: time is the tick's, which
is the simulation time of the vehicle's tick mark in lockstep (flight.lockstep) or the
autopilot's own `time_boot_ms` when free-running. Every message from the vehicle is applied
to `Telemetry` in arrival order; in lockstep the link is cut exactly at the tick's mark, and
what arrived after it waits for the next tick, so a decision sees exactly the vehicle's state
up to the frame it was taken on.
"""

from __future__ import annotations

import time
from collections import deque

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import Setpoint
from flight.lockstep import NS_PER_US, is_mark
from hil.autopilots import UnknownAutopilot
from hil.link import MavlinkLink
from hil.telemetry import Telemetry, local_setpoint, reposition_command, update_telemetry

M = mavlink2
COMPANION_COMPONENT = M.MAV_COMP_ID_ONBOARD_COMPUTER  # 191 (CONVENTIONS.md)


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
        elif t == "LOCAL_POSITION_NED":
            tel = self.tel
            self.telemetry_t = self.t
            self.positions.append((msg.time_boot_ms / 1000.0, tel.pos_ned, tel.vel_ned,
                                   tel.mode.name if tel.mode else "", tel.armed))  # fmt: skip
        elif t == "COMMAND_ACK":
            self.acks[msg.command] = msg.result
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
