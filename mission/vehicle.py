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
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode, Setpoint
from flight.geo import GRAVITY
from flight.lockstep import NS_PER_US, is_mark
from flight.mavlink.modes import Personality, mode_of_packed
from flight.state import VehicleState
from hil.link import MavlinkLink

M = mavlink2
COMPANION_COMPONENT = M.MAV_COMP_ID_ONBOARD_COMPUTER  # 191 (CONVENTIONS.md)


@dataclass
class Telemetry:
    """The newest of what the vehicle said about itself (SI, NED about home)."""

    time_boot_ms: int = 0
    armed: bool = False
    mode: FlightMode | None = None
    personality: Personality = Personality.PX4
    pos_ned: np.ndarray | None = None
    vel_ned: np.ndarray | None = None
    quat: np.ndarray | None = None  # (w, x, y, z) body FRD → NED
    omega_frd: np.ndarray | None = None  # [rad/s]
    landed_state: int = 0
    home_ok: bool = False
    statustext: str = ""

    def vehicle_state(self) -> VehicleState | None:
        """As a VehicleState (None until position and attitude have arrived)."""
        if self.pos_ned is None or self.quat is None:
            return None
        return VehicleState(t=self.time_boot_ms / 1000.0, pos_ned=self.pos_ned, vel_ned=self.vel_ned,
                            quat=self.quat, omega_frd=self.omega_frd, accel_frd=np.array([0.0, 0.0, -GRAVITY]),
                            on_ground=self.landed_state == M.MAV_LANDED_STATE_ON_GROUND)  # fmt: skip


class LinkLost(Exception):
    """Nothing arrived from the vehicle for longer than the wall-time patience."""


class VehicleLink:
    """One autopilot seen from the companion: telemetry, command acks, status texts."""

    def __init__(self, link: MavlinkLink, target_system: int | None = None):
        self.link = link
        self.target_system = target_system
        self.tel = Telemetry()
        self.acks: dict[int, int] = {}  # MAV_CMD → last MAV_RESULT
        self.statustexts: list[tuple[float, str]] = []  # (tick time [s], text)
        self.t = 0.0  # the current tick's time [s]
        self.heartbeat_t: float | None = None  # tick time of the last autopilot heartbeat [s]
        self.telemetry_t: float | None = None  # tick time of the last position sample [s]
        self.positions: list[tuple[float, np.ndarray, np.ndarray, str, bool]] = []
        self.setpoint: Setpoint | None = None  # streamed every tick while set (offboard)
        self._held: deque = deque()
        self._last_mark_ns = -1

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

    def drain(self, timeout_s: float) -> None:
        """Free-running: apply whatever arrives within `timeout_s` [s of wall time]; the tick
        time follows the autopilot's clock."""
        if not self._held:
            self._pull(timeout_s)
        while True:
            while self._held:
                self.apply(self._held.popleft())
            if not self._pull(0.0):
                break
        self.t = self.tel.time_boot_ms / 1000.0

    def close_tick(self) -> None:
        """Lockstep: tell the vehicle this tick's decision has been sent."""
        self.link.send(
            self.link.mav.timesync_encode(max(1, self._last_mark_ns), self._last_mark_ns)
        )

    def _from_vehicle(self, msg) -> bool:
        return self.target_system is None or msg.get_srcSystem() == self.target_system

    def apply(self, msg) -> None:
        """One message from the vehicle → Telemetry (the message's own fields, SI)."""
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        t = msg.get_type()
        if self.target_system is None and t == "HEARTBEAT" and comp == 1:
            self.target_system = src
        if src != self.target_system:
            return
        tel = self.tel
        if t == "HEARTBEAT" and comp == 1:
            tel.armed = bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
            if msg.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
                tel.personality = Personality.ARDUPILOT
            tel.mode = mode_of_packed(tel.personality, msg.custom_mode)
            self.heartbeat_t = self.t
        elif t == "LOCAL_POSITION_NED":
            tel.time_boot_ms = msg.time_boot_ms
            tel.pos_ned = np.array([msg.x, msg.y, msg.z])
            tel.vel_ned = np.array([msg.vx, msg.vy, msg.vz])
            self.telemetry_t = self.t
            self.positions.append((msg.time_boot_ms / 1000.0, tel.pos_ned, tel.vel_ned,
                                   tel.mode.name if tel.mode else "", tel.armed))  # fmt: skip
        elif t == "ATTITUDE_QUATERNION":
            tel.quat = np.array([msg.q1, msg.q2, msg.q3, msg.q4])
            tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
        elif t == "EXTENDED_SYS_STATE":
            tel.landed_state = msg.landed_state
        elif t == "HOME_POSITION":
            tel.home_ok = True
            self.home_amsl_m = msg.altitude / 1000.0
        elif t == "COMMAND_ACK":
            self.acks[msg.command] = msg.result
        elif t == "STATUSTEXT":
            text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
            tel.statustext = text
            self.statustexts.append((self.t, text))

    home_amsl_m: float = 0.0

    # ---- sending -----------------------------------------------------------------------------
    def send(self, msg) -> None:
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
        """SET_POSITION_TARGET_LOCAL_NED, stamped with the tick's time (the frame it answers)."""
        from flight.mavlink.offboard import (
            IGNORE_ACC,
            IGNORE_POS,
            IGNORE_VEL,
            IGNORE_YAW,
            IGNORE_YAW_RATE,
        )

        mask = IGNORE_ACC | IGNORE_YAW_RATE
        p = [0.0, 0.0, 0.0] if pos_ned is None else [float(x) for x in pos_ned]
        v = [0.0, 0.0, 0.0] if vel_ned is None else [float(x) for x in vel_ned]
        mask |= IGNORE_POS if pos_ned is None else 0
        mask |= IGNORE_VEL if vel_ned is None else 0
        mask |= IGNORE_YAW if yaw is None else 0
        stamp = round(1000 * (self.t if stamp_s is None else stamp_s))
        self.send(M.MAVLink_set_position_target_local_ned_message(
            stamp, self.target_system or 1, 1, M.MAV_FRAME_LOCAL_NED, mask, *p, *v,
            0.0, 0.0, 0.0, 0.0 if yaw is None else float(yaw), 0.0))  # fmt: skip
