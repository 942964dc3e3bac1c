"""Frames and rotations. The one place where NED and PyBullet's z-up ENU meet.

World: local NED about home. Body: FRD. Quaternions are (w, x, y, z), body → world.
PyBullet / ENU world: x east, y north, z up.
"""

from __future__ import annotations

import math

import numpy as np

# NED → ENU is a fixed permutation with a sign; it is its own inverse.
_NED_TO_ENU = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])


def ned_to_enu(v_ned: np.ndarray) -> np.ndarray:
    """Vector(s) in NED → ENU (PyBullet's z-up world). Shape (..., 3)."""
    return np.asarray(v_ned, dtype=float) @ _NED_TO_ENU.T


def enu_to_ned(v_enu: np.ndarray) -> np.ndarray:
    """Vector(s) in ENU (PyBullet's z-up world) → NED. Shape (..., 3)."""
    return np.asarray(v_enu, dtype=float) @ _NED_TO_ENU.T


def yaw_ned_to_enu(yaw_ned: float) -> float:
    """Heading from north, clockwise [rad] → ENU yaw from east, counter-clockwise [rad]."""
    return wrap_pi(math.pi / 2.0 - yaw_ned)


def yaw_enu_to_ned(yaw_enu: float) -> float:
    """ENU yaw from east, counter-clockwise [rad] → heading from north, clockwise [rad]."""
    return wrap_pi(math.pi / 2.0 - yaw_enu)


def wrap_pi(a: float) -> float:
    """Angle wrapped to [-pi, pi)."""
    return (a + math.pi) % (2.0 * math.pi) - math.pi


def quat_to_dcm(q: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) body → world from a unit quaternion (w, x, y, z)."""
    w, x, y, z = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def euler_to_quat(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Quaternion (w, x, y, z) from ZYX Euler angles [rad] (yaw, then pitch, then roll)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array(
        [
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ]
    )


def quat_to_euler(q: np.ndarray) -> tuple[float, float, float]:
    """ZYX Euler angles (roll, pitch, yaw) [rad] from a quaternion (w, x, y, z)."""
    w, x, y, z = q.tolist() if isinstance(q, np.ndarray) else q  # floats: 3x numpy scalars' speed
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


def quat_ned_to_enu(q_ned: np.ndarray) -> np.ndarray:
    """Body(FRD)→NED quaternion → body(FLU)→ENU quaternion (x, y, z, w order for PyBullet)."""
    r_ned = quat_to_dcm(q_ned)
    frd_to_flu = np.diag([1.0, -1.0, -1.0])
    r_enu = _NED_TO_ENU @ r_ned @ frd_to_flu
    return _dcm_to_quat_xyzw(r_enu)


def _dcm_to_quat_xyzw(r: np.ndarray) -> np.ndarray:
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        w, x, y, z = (
            0.25 * s,
            (r[2, 1] - r[1, 2]) / s,
            (r[0, 2] - r[2, 0]) / s,
            (r[1, 0] - r[0, 1]) / s,
        )
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
        w, x, y, z = (
            (r[2, 1] - r[1, 2]) / s,
            0.25 * s,
            (r[0, 1] + r[1, 0]) / s,
            (r[0, 2] + r[2, 0]) / s,
        )
    elif r[1, 1] > r[2, 2]:
        s = math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
        w, x, y, z = (
            (r[0, 2] - r[2, 0]) / s,
            (r[0, 1] + r[1, 0]) / s,
            0.25 * s,
            (r[1, 2] + r[2, 1]) / s,
        )
    else:
        s = math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
        w, x, y, z = (
            (r[1, 0] - r[0, 1]) / s,
            (r[0, 2] + r[2, 0]) / s,
            (r[1, 2] + r[2, 1]) / s,
            0.25 * s,
        )
    return np.array([x, y, z, w])
