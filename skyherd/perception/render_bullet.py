"""PyBullet renderer: the ground world seen by the UAV's camera (TinyRenderer, CPU, headless).

Same interface as `FastRenderer`: `render(uav, ugv_states) -> frame (H, W, 3) uint8 RGB`.
The view and projection matrices are built from `perception.camera` so that a world point
lands on the same pixel as `project()` says:

- eye = lens position, target = eye + optical axis, up = image-up (−y_cam), all converted
  NED → ENU with `flight.frames.ned_to_enu`;
- OpenGL projection with the camera's vertical field of view and aspect W/H, its principal
  point moved half a pixel because TinyRenderer samples pixel corners, so that pixel centres
  follow u = fx·x/z + (W − 1)/2: the same convention as `project` (checked in the tests).

Ground compositing (default): TinyRenderer spends ~85 % of a 320×240 frame filling the ground
plane, which under a directional light without shadows is ONE uniform colour at every pixel
and attitude (measured). The renderer measures that shaded colour once (an 8×8 render of bare
field), hides the ground's visual shape, renders the UGVs only, and paints the untouched
(pure white background) pixels with the measured colour: the frame is pixel-identical to
rasterising the ground (tested) at ~5× the speed. The ground stays in the physics. Set
`composite_ground=False` to rasterise it anyway. (It assumes the view stays below the horizon.)

If `ugv_states` is not the world's own latest state, the UGV bodies are first moved to it
(`GroundWorld.place`), so either renderer can draw any layout.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from skyherd.flight.frames import ned_to_enu
from skyherd.groundsim.ugv import UGVStates
from skyherd.groundsim.world import GroundWorld
from skyherd.perception.camera import CameraParams, camera_pose, check_pose


@dataclass(frozen=True)
class BulletRenderParams:
    light_direction_enu: tuple[float, float, float] = (0.4, 0.3, 1.0)  # towards the light
    shadow: bool = False  # TinyRenderer shadows cost time and smear markers
    # Composite the flat ground instead of rasterising it (see the module docstring).
    composite_ground: bool = True


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
        self.ground_rgb: np.ndarray | None = None
        if self.params.composite_ground:
            self.ground_rgb = self._measure_ground_colour()
            pb.changeVisualShape(
                world.ground_id, -1, rgbaColor=[0, 0, 0, 0], physicsClientId=world.cid
            )

    def _measure_ground_colour(self) -> np.ndarray:
        """The lit ground's colour: an 8×8 view of bare field far from the UGVs."""
        pb, w = self.world.pb, self.world
        g = 0.9 * w.p.ground_half_m
        view = pb.computeViewMatrix([g, g, 20.0], [g, g, 0.0], [0, 1, 0], physicsClientId=w.cid)
        proj = pb.computeProjectionMatrixFOV(30.0, 1.0, 0.1, 100.0, physicsClientId=w.cid)
        _, _, rgba, _, _ = pb.getCameraImage(
            8, 8, view, proj, lightDirection=list(self.params.light_direction_enu),
            shadow=int(self.params.shadow), renderer=pb.ER_TINY_RENDERER,
            flags=pb.ER_NO_SEGMENTATION_MASK, physicsClientId=w.cid,
        )  # fmt: skip
        return np.asarray(rgba, dtype=np.uint8).reshape(8, 8, 4)[4, 4, :3].copy()

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
        """Frame (H, W, 3) uint8 RGB. A non-finite UAV pose raises ValueError."""
        check_pose(uav.pos_ned, uav.quat)
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
        img = np.ascontiguousarray(
            np.asarray(rgba, dtype=np.uint8).reshape(cam.height_px, cam.width_px, 4)[..., :3]
        )
        if self.ground_rgb is not None:
            img[cv2.inRange(img, (255, 255, 255), (255, 255, 255)) > 0] = self.ground_rgb
        return img
