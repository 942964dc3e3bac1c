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
    marker_corners_ned,
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

    def _hull_corners(self, states: UGVStates) -> np.ndarray:
        """(N, 8, 3) NED corners of each hull box [m]."""
        m = self.model
        c, s = np.cos(states.heading), np.sin(states.heading)
        fwd = np.stack([c, s], -1)
        right = np.stack([-s, c], -1)
        signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=float)
        ne = states.pos_ne[:, None, :] + (
            0.5 * m.length_m * signs[None, :, 0:1] * fwd[:, None, :]
            + 0.5 * m.width_m * signs[None, :, 1:2] * right[:, None, :]
        )
        out = np.empty((states.n, 8, 3))
        out[:, :4, :2] = ne
        out[:, 4:, :2] = ne
        out[:, :4, 2] = 0.0
        out[:, 4:, 2] = -m.height_m
        return out

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
        hull_uv, hz = project(cam, pose, self._hull_corners(ugv_states))
        mark_uv, mz = project(cam, pose, marker_corners_ned(ugv_states, self.model))
        lim = 4.0 * (cam.width_px + cam.height_px)  # keep fixed-point coordinates in range
        for i in range(ugv_states.n):
            if (hz[i] > cam.near_m).all() and np.abs(hull_uv[i] - cam.centre_px).max() < lim:
                pts = np.round((hull_uv[i] + 0.0) * _SCALE).astype(np.int32)
                cv2.fillConvexPoly(img, cv2.convexHull(pts), BODY_RGB, cv2.LINE_AA, _SHIFT)
        for i in range(ugv_states.n):
            if (mz[i] > cam.near_m).all() and np.abs(mark_uv[i] - cam.centre_px).max() < lim:
                colour = (
                    GROUND_RGB
                    if ugv_states.camouflaged[i]
                    else MARKER_COLOURS[i % len(MARKER_COLOURS)]
                )
                pts = np.round(mark_uv[i] * _SCALE).astype(np.int32)
                cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, _SHIFT)
        if self.params.noise_std > 0:
            noise = self.rng.normal(0.0, self.params.noise_std, img.shape)
            img[...] = np.clip(img + noise, 0, 255).astype(np.uint8)
        return img
