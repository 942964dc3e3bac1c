"""skyherd's own MAVLink client: talks to our SITL or a real PX4 / ArduPilot autopilot.

It keeps the newest message of each type, speaks the command protocol with retries and typed
errors, and streams offboard setpoints paced by the vehicle's own telemetry (one setpoint per
LOCAL_POSITION_NED), so the stream rate holds in simulation time at any speed-up.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode
from flight.geo import GRAVITY
from flight.mavlink.modes import Personality, custom_mode_of, mode_of_packed
from flight.mavlink.offboard import IGNORE_ACC, IGNORE_POS, IGNORE_VEL, IGNORE_YAW, IGNORE_YAW_RATE
from flight.state import VehicleState
from hil.link import MavlinkLink


class CommandError(Exception):
    """A command was not accepted. `result` is the MAV_RESULT (or None on timeout)."""

    def __init__(self, command: int, result: int | None, detail: str = ""):
        name = mavlink2.enums["MAV_CMD"].get(command)
        cname = name.name if name else str(command)
        rname = "TIMEOUT" if result is None else mavlink2.enums["MAV_RESULT"][result].name
        super().__init__(f"{cname} failed: {rname}{(' — ' + detail) if detail else ''}")
        self.command, self.result = command, result


class ClientTimeout(Exception):
    """The vehicle did not answer or reach a state in time."""


@dataclass
class Telemetry:
    """The client's view of the vehicle (SI, NED about home)."""

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
        """The telemetry as a VehicleState (None until position and attitude arrived)."""
        if self.pos_ned is None or self.quat is None:
            return None
        return VehicleState(
            t=self.time_boot_ms / 1000.0,
            pos_ned=self.pos_ned,
            vel_ned=self.vel_ned,
            quat=self.quat,
            omega_frd=self.omega_frd,
            accel_frd=np.array([0.0, 0.0, -GRAVITY]),
            on_ground=self.landed_state == mavlink2.MAV_LANDED_STATE_ON_GROUND,
        )


class VehicleClient:
    """A ground-station-like client for one vehicle (system id `target_system`)."""

    def __init__(self, link: MavlinkLink, target_system: int | None = None, target_component=1):
        self.link = link
        self.target_system = target_system
        self.target_component = target_component
        self.telemetry = Telemetry()
        self._latest: dict[str, mavlink2.MAVLink_message] = {}
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._offboard: Callable[[Telemetry], mavlink2.MAVLink_message | None] | None = None
        self._acks: dict[int, int] = {}
        self._rx = threading.Thread(target=self._rx_loop, name="mav-rx", daemon=True)
        self._hb = threading.Thread(target=self._hb_loop, name="mav-hb", daemon=True)
        self.statustexts: list[str] = []

    # ---- lifecycle -------------------------------------------------------------------
    def start(self) -> VehicleClient:
        self._rx.start()
        self._hb.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._rx.join(timeout=1.0)
        self._hb.join(timeout=1.0)
        self.link.close()

    def __enter__(self) -> VehicleClient:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- receive ---------------------------------------------------------------------
    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            for msg in self.link.recv(0.05):
                self._handle(msg)

    def _hb_loop(self) -> None:
        while not self._stop.wait(1.0):
            self.link.send(
                mavlink2.MAVLink_heartbeat_message(
                    mavlink2.MAV_TYPE_GCS, mavlink2.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3
                )
            )

    def _handle(self, msg: mavlink2.MAVLink_message) -> None:
        src = msg.get_srcSystem()
        if (
            self.target_system is None
            and msg.get_type() == "HEARTBEAT"
            and msg.get_srcComponent() == 1
        ):
            self.target_system = src
        if src != self.target_system:
            return
        t = msg.get_type()
        tel = self.telemetry
        if t == "HEARTBEAT" and msg.get_srcComponent() == self.target_component:
            tel.armed = bool(msg.base_mode & mavlink2.MAV_MODE_FLAG_SAFETY_ARMED)
            if msg.autopilot == mavlink2.MAV_AUTOPILOT_ARDUPILOTMEGA:
                tel.personality = Personality.ARDUPILOT
            tel.mode = mode_of_packed(tel.personality, msg.custom_mode)
        elif t == "LOCAL_POSITION_NED":
            tel.time_boot_ms = msg.time_boot_ms
            tel.pos_ned = np.array([msg.x, msg.y, msg.z])
            tel.vel_ned = np.array([msg.vx, msg.vy, msg.vz])
            if self._offboard is not None:
                sp = self._offboard(tel)
                if sp is not None:
                    self.link.send(sp)
        elif t == "ATTITUDE_QUATERNION":
            tel.quat = np.array([msg.q1, msg.q2, msg.q3, msg.q4])
            tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
        elif t == "EXTENDED_SYS_STATE":
            tel.landed_state = msg.landed_state
        elif t == "HOME_POSITION":
            tel.home_ok = True
        elif t == "COMMAND_ACK":
            self._acks[msg.command] = msg.result
        elif t == "STATUSTEXT":
            tel.statustext = msg.text
            self.statustexts.append(msg.text)
        with self._cond:
            self._latest[t] = msg
            self._cond.notify_all()

    def latest(self, msg_type: str) -> mavlink2.MAVLink_message | None:
        return self._latest.get(msg_type)

    def wait_until(self, predicate: Callable[[], bool], timeout: float, what: str) -> None:
        """Wait (wall time) until `predicate()` holds; raise ClientTimeout naming `what`."""
        deadline = time.monotonic() + timeout
        with self._cond:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    raise ClientTimeout(f"timed out after {timeout:.0f} s waiting for {what}")
                self._cond.wait(min(left, 0.1))

    def wait_message(self, msg_type: str, timeout: float = 5.0) -> mavlink2.MAVLink_message:
        before = self._latest.get(msg_type)
        self.wait_until(lambda: self._latest.get(msg_type) not in (None, before), timeout, msg_type)
        return self._latest[msg_type]

    def wait_connected(self, timeout: float = 10.0) -> None:
        self.wait_until(
            lambda: self.target_system is not None and self.telemetry.mode is not None,
            timeout,
            "a vehicle heartbeat",
        )

    def wait_ready(self, timeout: float = 20.0) -> None:
        """Heartbeat, home position and local position all present."""
        self.wait_connected(timeout)
        self.request_message(mavlink2.MAVLINK_MSG_ID_HOME_POSITION)
        self.wait_until(
            lambda: self.telemetry.home_ok and self.telemetry.pos_ned is not None,
            timeout,
            "home and local position",
        )

    # ---- commands --------------------------------------------------------------------
    def command_long(
        self, command: int, *params: float, timeout: float = 1.5, retries: int = 3
    ) -> int:
        """Send COMMAND_LONG until acknowledged; return MAV_RESULT, raise CommandError unless accepted."""
        p = list(params) + [0.0] * (7 - len(params))
        for confirmation in range(retries):
            self._acks.pop(command, None)
            self.link.send(
                mavlink2.MAVLink_command_long_message(
                    self.target_system, self.target_component, command, confirmation, *p
                )
            )
            try:
                self.wait_until(
                    lambda: (
                        self._acks.get(command, mavlink2.MAV_RESULT_IN_PROGRESS)
                        != mavlink2.MAV_RESULT_IN_PROGRESS
                    ),
                    timeout,
                    "COMMAND_ACK",
                )
            except ClientTimeout:
                continue
            result = self._acks[command]
            if result != mavlink2.MAV_RESULT_ACCEPTED:
                raise CommandError(command, result, self.telemetry.statustext)
            return result
        raise CommandError(command, None)

    def request_message(self, msg_id: int) -> None:
        try:
            self.command_long(mavlink2.MAV_CMD_REQUEST_MESSAGE, msg_id, retries=1, timeout=0.5)
        except CommandError:
            pass  # older autopilots: the stream will bring it anyway

    def arm(self, force: bool = False) -> None:
        self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196 if force else 0)

    def disarm(self, force: bool = False) -> None:
        self.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)

    def set_mode(self, mode: FlightMode) -> None:
        packed = custom_mode_of(self.telemetry.personality, mode)
        if self.telemetry.personality is Personality.PX4:
            main, sub = (packed >> 16) & 0xFF, (packed >> 24) & 0xFF
        else:
            main, sub = packed, 0
        self.command_long(
            mavlink2.MAV_CMD_DO_SET_MODE, mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub
        )

    def takeoff(self, altitude: float) -> None:
        self.command_long(
            mavlink2.MAV_CMD_NAV_TAKEOFF,
            0,
            0,
            0,
            math.nan,
            math.nan,
            math.nan,
            altitude + self.home_amsl(),
        )

    def land(self) -> None:
        self.command_long(
            mavlink2.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan
        )

    def home_amsl(self) -> float:
        home = self.latest("HOME_POSITION")
        return home.altitude / 1000.0 if home is not None else 0.0

    # ---- offboard --------------------------------------------------------------------
    def stream_offboard(self, setpoint: Callable[[Telemetry], tuple | None] | None) -> None:
        """Send a setpoint on every LOCAL_POSITION_NED; `setpoint(tel)` returns
        (pos_ned or None, vel_ned or None, yaw or None) or None to send nothing. None stops."""
        if setpoint is None:
            self._offboard = None
            return

        def make(tel: Telemetry):
            sp = setpoint(tel)
            return None if sp is None else self.position_target(*sp)

        self._offboard = make

    def position_target(self, pos_ned=None, vel_ned=None, yaw=None) -> mavlink2.MAVLink_message:
        mask = IGNORE_ACC | IGNORE_YAW_RATE
        p = [0.0, 0.0, 0.0] if pos_ned is None else [float(x) for x in pos_ned]
        v = [0.0, 0.0, 0.0] if vel_ned is None else [float(x) for x in vel_ned]
        mask |= IGNORE_POS if pos_ned is None else 0
        mask |= IGNORE_VEL if vel_ned is None else 0
        mask |= IGNORE_YAW if yaw is None else 0
        return mavlink2.MAVLink_set_position_target_local_ned_message(
            self.telemetry.time_boot_ms, self.target_system, self.target_component,
            mavlink2.MAV_FRAME_LOCAL_NED, mask, *p, *v, 0.0, 0.0, 0.0,
            0.0 if yaw is None else float(yaw), 0.0,
        )  # fmt: skip
