"""A camera frame as the onboard computer has it, and the camera pose it computes.

A real onboard computer has the camera's pixels with their capture time, the camera's
intrinsics and mounting (its configuration: perception.camera.CameraParams and the mount of
hil.camera_mount, which the simulator's camera_info record announces too), and the autopilot's
estimate of the vehicle's pose from MAVLink telemetry. It never has the simulator's truth.

`CameraFrame` is all a mission receives of a frame (mission.companion.FrameInbox builds it):
the capture time, the sequence number, the pixels, the estimated vehicle pose at the capture
time and where the companion had pointed the gimbal. The pose the simulator stamps in the
frame's header is for the records (docs/perception.md) and has no field here, so no mission can
read it. The camera pose at a frame = the estimated vehicle pose composed with the mount (and,
for a pointed head, the region of interest the gimbal acknowledged).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.mission.vehicle import VehicleLink
from skyherd.perception.camera import CameraParams, CameraPose, UAVPose
from skyherd.perception.mount import mounted_camera_pose


@dataclass(frozen=True)
class CameraFrame:
    """One frame on the onboard side. image (H, W, 3) uint8 RGB."""

    t: float  # capture time [s]: the frame's stamp (the simulation's / the autopilot's clock)
    seq: int  # the camera's frame counter
    image: np.ndarray
    vehicle: UAVPose | None  # the autopilot's estimate at t (None: no telemetry yet)
    roi_ned: np.ndarray | None = None  # where the gimbal was told to look (None: nadir)

    @property
    def altitude_m(self) -> float:
        """The estimated height above home at capture [m] (NaN without an estimate)."""
        return math.nan if self.vehicle is None else -float(self.vehicle.pos_ned[2])

    def camera_pose(self, cam: CameraParams, mount: str) -> CameraPose | None:
        """The camera's pose at capture from the estimate (None without one)."""
        if self.vehicle is None:
            return None
        return mounted_camera_pose(cam, mount, self.vehicle.pos_ned, self.vehicle.quat,
                                   self.roi_ned)  # fmt: skip


def onboard_frame(frame, v: VehicleLink | None) -> CameraFrame | None:
    """A received frame (perception.transport.Frame: the pixels and the simulator's header) →
    what the onboard computer has of it: its stamp, sequence and pixels, with the estimate of
    the vehicle `v` at the stamp. None stays None."""
    if frame is None:
        return None
    vehicle = None if v is None else v.pose_at(frame.t_sim)
    roi = None if v is None else v.roi_ned
    return CameraFrame(frame.t_sim, frame.seq, frame.image, vehicle, roi)
