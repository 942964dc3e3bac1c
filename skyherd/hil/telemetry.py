"""The vehicle as the companion sees it: MAVLink messages from PX4 / ArduCopter / ArduPlane
(or skyherd's built-in vehicle) decoded into `Telemetry`, SI and NED about home.

`update_telemetry(tel, msg, profile)` is the whole message → Telemetry step as a pure function
(the companion's VehicleLink applies every message through it, in arrival order). It finds the
autopilot from its first HEARTBEAT (hil/autopilots.py), decodes its modes, joins chunked
STATUSTEXTs, keeps the autopilot's clock (`time_boot_ms`) and every mode change (`modes`);
who may change the mode is mission/authority.py's business. `local_setpoint` and `reposition_command` build the two setpoint
messages (SET_POSITION_TARGET_LOCAL_NED, DO_REPOSITION) with home's offset added back.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.frames import euler_to_quat
from skyherd.flight.geo import GRAVITY, Home, ned_to_geodetic
from skyherd.flight.mavlink.modes import Personality
from skyherd.flight.mavlink.offboard import (
    IGNORE_ACC,
    IGNORE_POS,
    IGNORE_VEL,
    IGNORE_YAW,
    IGNORE_YAW_RATE,
)
from skyherd.flight.state import VehicleState
from skyherd.hil.autopilots import AutopilotProfile, detect

M = mavlink2
ON_GROUND, IN_AIR = M.MAV_LANDED_STATE_ON_GROUND, M.MAV_LANDED_STATE_IN_AIR
STATUSTEXT_CHUNK = 50  # characters in one STATUSTEXT; a shorter chunk ends the text
MAX_TEXTS = 200  # STATUSTEXTs kept in Telemetry (the newest)


@dataclass
class Telemetry:
    """The companion's view of one vehicle (SI, NED about home)."""

    time_boot_ms: int = 0
    armed: bool = False
    mode: FlightMode | None = None
    personality: Personality = Personality.PX4
    pos_ned: np.ndarray | None = None  # about home (LOCAL_POSITION_NED less home's x, y, z)
    vel_ned: np.ndarray | None = None
    quat: np.ndarray | None = None  # (w, x, y, z) body FRD → NED
    omega_frd: np.ndarray | None = None  # [rad/s]
    landed_state: int = 0
    home_ok: bool = False
    statustext: str = ""
    # --- added for real autopilots -----------------------------------------------------------
    profile: AutopilotProfile | None = None
    custom_mode: int | None = None
    mode_name: str = ""  # the autopilot's own name (BRAKE, AUTO.LOITER, ...)
    system_status: int = 0
    home: Home | None = None  # home position (latitude, longitude, AMSL)
    home_local: np.ndarray = field(default_factory=lambda: np.zeros(3))  # home in LOCAL_NED
    gps_fix: int | None = None
    ekf_flags: int | None = None
    prearm_ok: bool | None = None  # SYS_STATUS pre-arm bit (None: not reported)
    extended_sys_state_seen: bool = False
    quaternion_seen: bool = False
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)  # (t, severity, text)
    statustext_total: int = 0  # STATUSTEXTs received in all (statustexts keeps the newest)
    modes: list[tuple[float, str]] = field(default_factory=list)  # (t, name) at each change
    reboots: int = 0
    _chunks: dict[int, list[str]] = field(default_factory=dict, repr=False)

    @property
    def t(self) -> float:
        """The autopilot's time [s]."""
        return self.time_boot_ms / 1000.0

    def vehicle_state(self) -> VehicleState | None:
        """The telemetry as a VehicleState (None until position and attitude arrived)."""
        if self.pos_ned is None or self.quat is None:
            return None
        return VehicleState(
            t=self.time_boot_ms / 1000.0,
            pos_ned=self.pos_ned,
            vel_ned=self.vel_ned,
            quat=self.quat,
            omega_frd=self.omega_frd if self.omega_frd is not None else np.zeros(3),
            accel_frd=np.array([0.0, 0.0, -GRAVITY]),
            on_ground=self.landed_state == ON_GROUND,
        )


def update_telemetry(tel: Telemetry, msg, profile: AutopilotProfile | None = None) -> None:
    """Apply one message from the autopilot (component 1 of the vehicle) to `tel`.

    `profile` overrides the one detected from the first HEARTBEAT (kept in `tel.profile`).
    Raises UnknownAutopilot for a HEARTBEAT of an autopilot skyherd cannot fly."""
    t = msg.get_type()
    if profile is not None:
        tel.profile = profile
    if hasattr(msg, "time_boot_ms") and t != "HEARTBEAT":
        _advance_clock(tel, int(msg.time_boot_ms))
    if t == "HEARTBEAT":
        if tel.profile is None:
            tel.profile = detect(msg.autopilot, msg.type)
        _on_heartbeat(tel, msg)
    elif t == "LOCAL_POSITION_NED":
        tel.pos_ned = np.array([msg.x, msg.y, msg.z]) - tel.home_local
        tel.vel_ned = np.array([msg.vx, msg.vy, msg.vz])
        _derive_landed(tel)
    elif t == "ATTITUDE_QUATERNION":
        tel.quaternion_seen = True
        tel.quat = np.array([msg.q1, msg.q2, msg.q3, msg.q4])
        tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
    elif t == "ATTITUDE" and not tel.quaternion_seen:
        tel.quat = euler_to_quat(msg.roll, msg.pitch, msg.yaw)
        tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
    elif t == "EXTENDED_SYS_STATE":
        tel.extended_sys_state_seen = True
        tel.landed_state = msg.landed_state
    elif t == "HOME_POSITION":
        tel.home_ok = True
        tel.home = Home(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
        new = np.array([msg.x, msg.y, msg.z], dtype=float)
        if tel.pos_ned is not None:
            tel.pos_ned = tel.pos_ned + tel.home_local - new
        tel.home_local = new
    elif t == "GPS_RAW_INT":
        tel.gps_fix = msg.fix_type
    elif t == "EKF_STATUS_REPORT":
        tel.ekf_flags = msg.flags
    elif t == "SYS_STATUS":
        if msg.onboard_control_sensors_present & M.MAV_SYS_STATUS_PREARM_CHECK:
            tel.prearm_ok = bool(msg.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
    elif t == "STATUSTEXT":
        text = _join_statustext(tel, msg)
        if text is not None:
            tel.statustext = text
            tel.statustexts.append((tel.t, int(msg.severity), text))
            tel.statustext_total += 1
            if len(tel.statustexts) > 2 * MAX_TEXTS:
                del tel.statustexts[:-MAX_TEXTS]


def _advance_clock(tel: Telemetry, ms: int) -> None:
    if ms >= tel.time_boot_ms:
        tel.time_boot_ms = ms
    elif tel.time_boot_ms - ms > 5000:  # the clock went back by more than any reordering
        tel.time_boot_ms = ms
        tel.reboots += 1


def _on_heartbeat(tel: Telemetry, msg) -> None:
    p = tel.profile
    tel.personality = p.personality
    tel.armed = bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    tel.system_status = msg.system_status
    if not msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return
    if tel.custom_mode != msg.custom_mode:
        name = p.mode_name(msg.custom_mode)
        tel.modes.append((tel.t, name))
        tel.custom_mode, tel.mode_name = msg.custom_mode, name
        tel.mode = p.decode_mode(msg.custom_mode)
    _derive_landed(tel)


def _derive_landed(tel: Telemetry) -> None:
    """Landed state where the autopilot sends no EXTENDED_SYS_STATE (ArduPilot by default):
    disarmed is on the ground; armed, within 0.5 m of home's altitude and not moving is too."""
    if tel.extended_sys_state_seen:
        return
    if not tel.armed:
        tel.landed_state = ON_GROUND
        return
    if tel.pos_ned is None or tel.vel_ned is None:
        return
    low = -tel.pos_ned[2] < 0.5 and float(np.linalg.norm(tel.vel_ned)) < 0.5
    tel.landed_state = ON_GROUND if low else IN_AIR


def _join_statustext(tel: Telemetry, msg) -> str | None:
    """A whole STATUSTEXT: chunks with the same non-zero id are joined in chunk_seq order."""
    text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
    text = text.split("\x00", 1)[0]
    text_id = int(getattr(msg, "id", 0) or 0)
    if text_id == 0:
        return text
    parts = tel._chunks.setdefault(text_id, [])
    seq = int(getattr(msg, "chunk_seq", 0) or 0)
    while len(parts) <= seq:
        parts.append("")
    parts[seq] = text
    if len(text) < STATUSTEXT_CHUNK:
        del tel._chunks[text_id]
        return "".join(parts)
    if len(tel._chunks) > 16:  # a lost last chunk never completes: forget the oldest
        tel._chunks.pop(next(iter(tel._chunks)))
    return None


def local_setpoint(tel: Telemetry, target_system: int, pos_ned=None, vel_ned=None, yaw=None,
                   target_component: int = 1, time_ms: int | None = None) -> mavlink2.MAVLink_message:  # fmt: skip
    """SET_POSITION_TARGET_LOCAL_NED for a position about home [m, NED] (home's x, y, z in
    the autopilot's local frame added back), velocity [m/s] and yaw [rad]; None: ignored.
    Stamped `time_ms` (default: the telemetry's time)."""
    mask = IGNORE_ACC | IGNORE_YAW_RATE
    home = tel.home_local
    p = [0.0, 0.0, 0.0] if pos_ned is None else [float(x + h) for x, h in zip(pos_ned, home)]
    v = [0.0, 0.0, 0.0] if vel_ned is None else [float(x) for x in vel_ned]
    mask |= IGNORE_POS if pos_ned is None else 0
    mask |= IGNORE_VEL if vel_ned is None else 0
    mask |= IGNORE_YAW if yaw is None else 0
    return M.MAVLink_set_position_target_local_ned_message(
        tel.time_boot_ms if time_ms is None else time_ms, target_system, target_component,
        M.MAV_FRAME_LOCAL_NED, mask, *p, *v,
        0.0, 0.0, 0.0, 0.0 if yaw is None else float(yaw), 0.0,
    )  # fmt: skip


def reposition_command(tel: Telemetry, profile: AutopilotProfile, target_system: int, pos_ned,
                       yaw=None, target_component: int = 1,
                       change_mode: bool = False) -> mavlink2.MAVLink_message:  # fmt: skip
    """DO_REPOSITION as COMMAND_INT to a position about home, in the global frame the profile
    names: PX4 accepts GLOBAL_INT frames only; ArduPlane's GUIDED takes its targets this way
    (GLOBAL_RELATIVE_ALT_INT). Needs `tel.home`. `change_mode`: param 2 bit 0, switch to the
    mode that flies it as well (ArduPlane: GUIDED, refused without it in TAKEOFF; PX4: Hold);
    never for a setpoint stream, which must not undo a hold the net asked for."""
    lat, lon, amsl = ned_to_geodetic(tel.home, np.asarray(pos_ned, dtype=float))
    relative = profile.reposition_frame == M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    z = amsl - tel.home.alt_m if relative else amsl
    return M.MAVLink_command_int_message(
        target_system, target_component, profile.reposition_frame, M.MAV_CMD_DO_REPOSITION, 0, 0,
        -1.0, float(M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE if change_mode else 0),
        0.0, math.nan if yaw is None else math.degrees(yaw),
        int(round(lat * 1e7)), int(round(lon * 1e7)), float(z),
    )  # fmt: skip


__all__ = ["Telemetry", "local_setpoint", "reposition_command", "update_telemetry"]
