"""How the camera is carried: one function for both ends of the camera link.

The simulator renders a frame from the vehicle's TRUE pose through the mount (world/sim.py,
world/follow.py); the companion knows only the autopilot's ESTIMATE (MAVLink telemetry) and
computes the pose the frame was taken from through the same mount (mission/onboard.py). So the
two differ exactly by the estimate's error, as on a real vehicle.

Mounts (`MOUNTS`):
  body     fixed to the airframe: perception.camera's mount (down, image top = forward)
  level    a roll/pitch-stabilised gimbal: the body mount with roll and pitch removed, the
           heading kept (the quadrotor's downward camera; the policy was trained with it)
  pointed  a stabilised pan-tilt head looking at a region of interest (hil.orbit_gimbal; the
           fixed-wing orbit's), straight down below the vehicle until one is set

`mounted_pose` returns the virtual body pose (pos_ned, quat) that the renderers and
`perception.camera.camera_pose` take.
"""

from __future__ import annotations

import numpy as np

from skyherd.flight.frames import euler_to_quat, quat_to_euler
from skyherd.perception.camera import CameraParams, CameraPose, UAVPose, camera_pose
from skyherd.perception.gimbal import gimbal_pose

MOUNTS = ("body", "level", "pointed")


def level_quat(quat) -> np.ndarray:
    """The attitude (w, x, y, z) a roll/pitch-stabilised gimbal holds: the heading of `quat`,
    level."""
    _, _, yaw = quat_to_euler(np.asarray(quat, dtype=float))
    return euler_to_quat(0.0, 0.0, yaw)


def mounted_pose(cam: CameraParams, mount: str, pos_ned, quat,
                 roi_ned: np.ndarray | None = None) -> UAVPose:  # fmt: skip
    """The virtual body pose whose body mount is the camera as carried by `mount`, for a
    vehicle at `pos_ned` (3,) NED [m] with attitude `quat` (w, x, y, z); `roi_ned` (3,) is
    where a pointed head looks (None: straight down). ValueError for an unknown mount."""
    pos = np.asarray(pos_ned, dtype=float)
    if mount == "body":
        return UAVPose(pos, np.asarray(quat, dtype=float))
    if mount not in MOUNTS:
        raise ValueError(f"camera mount must be one of {', '.join(MOUNTS)}, not {mount!r}")
    if mount == "level":
        return UAVPose(pos, level_quat(quat))
    _, _, yaw = quat_to_euler(np.asarray(quat, dtype=float))
    target = roi_ned if roi_ned is not None else np.array([pos[0], pos[1], 0.0])
    g = gimbal_pose(cam, pos, yaw, target)
    return UAVPose(g.pos_ned, g.quat)


def mounted_camera_pose(cam: CameraParams, mount: str, pos_ned, quat,
                        roi_ned: np.ndarray | None = None) -> CameraPose:  # fmt: skip
    """The camera's pose (lens position, camera → NED rotation) for a vehicle pose: the vehicle
    pose composed with the mount and the camera's own mounting (perception.camera)."""
    v = mounted_pose(cam, mount, pos_ned, quat, roi_ned)
    return camera_pose(cam, v.pos_ned, v.quat)
