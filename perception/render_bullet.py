"""PyBullet renderer: the ground world seen by the UAV's camera (TinyRenderer, CPU, headless).

Same interface as `FastRenderer`: `render(uav, ugv_states) -> frame (H, W, 3) uint8 RGB`.
The view and projection matrices are built from `perception.camera` so that a world point
lands on the same pixel as `project()` says:

- eye = lens position, target = eye + optical axis, up = image-up (−y_cam), all converted
  NED → ENU with `flight.frames.ned_to_enu`;
- OpenGL projection with the camera's vertical field of view and aspect W/H, its principal
  point moved half a pixel because TinyRenderer samples pixel corners, so that pixel centres
  follow u = fx·x/z + (W − 1)/2: the same convention as `project` (checked in the tests).

If `ugv_states` is not the world's own latest state, the UGV bodies are first moved to it
(`GroundWorld.place`), so either renderer can draw any layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from flight.frames import ned_to_enu
from groundsim.ugv import UGVStates
from groundsim.world import GroundWorld
from perception.camera import CameraParams, camera_pose


@dataclass(frozen=True)
class BulletRenderParams:
    light_direction_enu: tuple[float, float, float] = (0.4, 0.3, 1.0)  # towards the light
    shadow: bool = False  # TinyRenderer shadows cost time and smear markers


class BulletRenderer:
    """Renders a `GroundWorld` through its own PyBullet client."""

    def __init__(
        self, world: GroundWorld, cam: CameraParams, params: BulletRenderParams | None = None
    ):
        self.world, self.cam = world, cam
        self.params = params if params is not None else BulletRenderParams()
        pb = world.pb
        proj = list(
            pb.computeProjectionMatrixFOV(
                fov=math.degrees(cam.vfov_rad),
                aspect=cam.width_px / cam.height_px,
                nearVal=cam.near_m,
                farVal=cam.far_m,
                physicsClientId=world.cid,
            )
        )
        # TinyRenderer samples each pixel at its corner, not its centre: measured offset
        # (+0.5, −0.5) px against `project`. Shift the principal point half a pixel back
        # (column-major entries 8, 9: x_ndc and y_ndc offsets, 2/W per pixel).
        proj[8] += 1.0 / cam.width_px
        proj[9] += 1.0 / cam.height_px
        self._proj = proj

    def view_matrix(self, uav) -> list[float]:
        pose = camera_pose(self.cam, uav.pos_ned, uav.quat)
        r = pose.r_world_from_cam
        eye = ned_to_enu(pose.pos_ned)
        target = ned_to_enu(pose.pos_ned + r[:, 2])
        up = ned_to_enu(-r[:, 1])
        return self.world.pb.computeViewMatrix(
            eye.tolist(), target.tolist(), up.tolist(), physicsClientId=self.world.cid
        )

    def render(self, uav, ugv_states: UGVStates) -> np.ndarray:
        w = self.world
        if ugv_states is not w.states:
            w.place(ugv_states)
        pb, cam = w.pb, self.cam
        _, _, rgba, _, _ = pb.getCameraImage(
            cam.width_px,
            cam.height_px,
            self.view_matrix(uav),
            self._proj,
            lightDirection=list(self.params.light_direction_enu),
            shadow=int(self.params.shadow),
            renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK,
            physicsClientId=w.cid,
        )
        img = np.asarray(rgba, dtype=np.uint8).reshape(cam.height_px, cam.width_px, 4)
        return np.ascontiguousarray(img[..., :3])
