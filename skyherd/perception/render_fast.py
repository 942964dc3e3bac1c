"""Fast renderer: the UGVs' projected hulls and top markers rasterised with OpenCV.

Same interface as the PyBullet renderer: `render(uav, ugv_states) -> frame (H, W, 3) uint8 RGB`,
`uav` anything with `pos_ned` (3,) NED [m] and `quat` (w, x, y, z) body → NED. The geometry is
`perception.camera.project`, so pixels agree with the PyBullet renderer and the fast path.

Polygons are filled anti-aliased with 1/16-pixel vertex precision (cv2 `shift=4`), hulls first
(dark, as the convex hull of their 8 projected corners), then the markers. A camouflaged UGV's
marker takes the ground's colour. Optional Gaussian pixel noise (seeded) for robustness tests.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from skyherd.groundsim.ugv import (
    BODY_RGB,
    GROUND_RGB,
    MARKER_COLOURS,
    UGVModel,
    UGVStates,
    corners_ned,
)
from skyherd.perception.camera import CameraParams, camera_pose, check_pose, project

_SHIFT = 4  # fixed-point bits for cv2 polygon vertices
_SCALE = float(1 << _SHIFT)


@dataclass(frozen=True)
class FastRenderParams:
    noise_std: float = 0.0  # Gaussian pixel noise std [0..255 levels]; 0 = none


class FastRenderer:
    """OpenCV rasteriser of UGV hulls and markers on a flat ground."""

    def __init__(
        self,
        cam: CameraParams,
        model: UGVModel | None = None,
        params: FastRenderParams = FastRenderParams(),
        rng: np.random.Generator | None = None,
    ):
        self.cam, self.params = cam, params
        self.model = model if model is not None else UGVModel()
        self.rng = rng if rng is not None else np.random.default_rng(0)
        self._bg = np.empty((cam.height_px, cam.width_px, 3), dtype=np.uint8)
        self._bg[:] = GROUND_RGB
        self._lim = 4.0 * (cam.width_px + cam.height_px)  # keep fixed-point coordinates in range

    def render(self, uav, ugv_states: UGVStates, out: np.ndarray | None = None) -> np.ndarray:
        """Frame (H, W, 3) uint8 RGB, drawn into `out` when given (e.g. the frame publisher's
        buffer: perception.transport.FramePublisher.frame_buffer) and returned. A non-finite UAV
        pose raises ValueError (before `out` is touched)."""
        cam = self.cam
        check_pose(uav.pos_ned, uav.quat)
        pose = camera_pose(cam, uav.pos_ned, uav.quat)
        if out is None:
            img = self._bg.copy()
        else:
            if out.shape != self._bg.shape or out.dtype != np.uint8:
                raise ValueError(f"out must be {self._bg.shape} uint8, got {out.shape} {out.dtype}")
            img = out
            img[...] = self._bg
        uv, depth = project(cam, pose, corners_ned(ugv_states, self.model))
        # a polygon is drawn when each of its corners is before the near plane (behind the
        # camera: NaN) and not far out of the image (the fixed-point coordinates' range)
        drawn = (depth > cam.near_m) & (np.abs(uv - cam.centre_px).max(axis=2) < self._lim)
        hulls, markers = drawn[:, :8].all(axis=1).tolist(), drawn[:, 8:].all(axis=1).tolist()
        px = np.round(uv * _SCALE)  # fixed point, made int32 for the polygons drawn
        for i in range(ugv_states.n):
            if hulls[i]:
                pts = cv2.convexHull(px[i, :8].astype(np.int32))
                cv2.fillConvexPoly(img, pts, BODY_RGB, cv2.LINE_AA, _SHIFT)
        camouflaged = np.asarray(ugv_states.camouflaged).tolist()
        for i in range(ugv_states.n):
            if markers[i]:
                colour = GROUND_RGB if camouflaged[i] else MARKER_COLOURS[i % len(MARKER_COLOURS)]
                cv2.fillConvexPoly(img, px[i, 8:].astype(np.int32), colour, cv2.LINE_AA, _SHIFT)
        if self.params.noise_std > 0:
            noise = self.rng.normal(0.0, self.params.noise_std, img.shape)
            img[...] = np.clip(img + noise, 0, 255).astype(np.uint8)
        return img
