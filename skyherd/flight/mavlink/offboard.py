"""Offboard setpoints and manual control from MAVLink into the autopilot's terms.

SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT honour `type_mask` (a set bit = ignore that
field): a position or velocity vector is used only when all three of its axes are, yaw and
yaw rate each on their own. Setpoints that are not finite, too far, too fast, in an
unsupported frame or that command nothing are dropped (these messages have no answer)
and counted; the autopilot never sees them.
"""

from __future__ import annotations

import math

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.geo import Home, geodetic_to_ned

M = mavlink
MAX_RANGE_M = 100_000.0  # [m] from home
MAX_SPEED = 50.0  # [m/s]
MAX_YAW_RATE = 10.0  # [rad/s]

IGNORE_POS = 0b111
IGNORE_VEL = 0b111 << 3
IGNORE_ACC = 0b111 << 6
FORCE_SET = 1 << 9
IGNORE_YAW = 1 << 10
IGNORE_YAW_RATE = 1 << 11


class SetpointError(ValueError):
    """Why a setpoint was dropped."""


def setpoint_from_local(msg) -> Setpoint:
    """SET_POSITION_TARGET_LOCAL_NED in MAV_FRAME_LOCAL_NED → Setpoint (NED about home)."""
    if msg.coordinate_frame != M.MAV_FRAME_LOCAL_NED:
        raise SetpointError(f"frame {msg.coordinate_frame} unsupported (use LOCAL_NED)")
    return _setpoint(msg, lambda: np.array([msg.x, msg.y, msg.z], dtype=float))


def setpoint_from_global(msg, home: Home) -> Setpoint:
    """SET_POSITION_TARGET_GLOBAL_INT (GLOBAL_INT or GLOBAL_RELATIVE_ALT_INT) → Setpoint."""
    frame = msg.coordinate_frame
    if frame not in (M.MAV_FRAME_GLOBAL_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                     M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_RELATIVE_ALT):  # fmt: skip
        raise SetpointError(f"frame {frame} unsupported")

    def pos() -> np.ndarray:
        lat, lon = msg.lat_int / 1e7, msg.lon_int / 1e7
        if not (-90 <= lat <= 90 and -180 <= lon <= 180):
            raise SetpointError("latitude/longitude out of range")
        if not math.isfinite(msg.alt):
            raise SetpointError("altitude not finite")
        rel = frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT)
        alt_amsl = home.alt_m + msg.alt if rel else msg.alt
        return geodetic_to_ned(home, lat, lon, alt_amsl)

    return _setpoint(msg, pos)


def _setpoint(msg, position) -> Setpoint:
    mask = int(msg.type_mask)
    pos_bits, vel_bits = mask & IGNORE_POS, mask & IGNORE_VEL
    if pos_bits not in (0, IGNORE_POS) or vel_bits not in (0, IGNORE_VEL):
        raise SetpointError("partial position/velocity axes unsupported")
    if mask & FORCE_SET:
        raise SetpointError("force setpoints unsupported")
    pos = position() if pos_bits == 0 else None
    vel = np.array([msg.vx, msg.vy, msg.vz], dtype=float) if vel_bits == 0 else None
    yaw = float(msg.yaw) if not mask & IGNORE_YAW else None
    yaw_rate = float(msg.yaw_rate) if not mask & IGNORE_YAW_RATE else None
    sp = Setpoint(pos_ned=pos, vel_ned=vel, yaw=yaw, yaw_rate=yaw_rate)
    if pos is None and vel is None:
        raise SetpointError("neither position nor velocity commanded")
    if not sp.is_finite():
        raise SetpointError("setpoint not finite")
    if pos is not None and (np.linalg.norm(pos) > MAX_RANGE_M or pos[2] > 1.0):
        raise SetpointError("position out of range")
    if vel is not None and np.linalg.norm(vel) > MAX_SPEED:
        raise SetpointError("velocity out of range")
    if yaw is not None and abs(yaw) > 2 * math.pi:
        raise SetpointError("yaw out of range")
    if yaw_rate is not None and abs(yaw_rate) > MAX_YAW_RATE:
        raise SetpointError("yaw rate out of range")
    return sp


def manual_from_msg(msg) -> tuple[float, float, float, float]:
    """MANUAL_CONTROL (x, y, r in [-1000, 1000], z in [0, 1000]) → normalised sticks."""
    x, y, z, r = msg.x, msg.y, msg.z, msg.r
    if not (-1000 <= x <= 1000 and -1000 <= y <= 1000 and 0 <= z <= 1000 and -1000 <= r <= 1000):
        raise SetpointError("manual control out of range")
    return x / 1000.0, y / 1000.0, z / 1000.0, r / 1000.0
