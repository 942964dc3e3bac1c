"""The feature vector φ(s) the learners use, from UGV pixel positions.

The same code serves the detector (centroids found in a frame) and the fast path (true
centroids projected through `perception.camera`, no pixels at all), so a policy trained on the
fast path sees the same numbers in flight.

φ(s), shape (8,), every entry in [0, 1]:

====  ==============  ========================================================================
idx   name            meaning
====  ==============  ========================================================================
0     com_u           0.5 + (ū − cx) / W: UGVs' centre of mass across the image (0.5 = centred)
1     com_v           0.5 + (v̄ − cy) / H: same, down the image
2     spread          r / (½·√(W² + H²)): minimum enclosing circle radius relative to the
                      half-diagonal (a circle around points inside the image never exceeds 1)
3     altitude        altitude / altitude_max_m, clipped
4     frac_in_view    detected UGVs / UGVs in the team
5     all_in_view     1 when every UGV of the team is detected, else 0
6     edge_margin     min distance of a detected UGV to the image border / (½·min(W, H))
7     frame_ok        1 when a frame (or a fast-path measurement) arrived, else 0
====  ==============  ========================================================================

Honest degradation (encoded, never hidden):
- UGV out of view or camouflaged and missed: frac_in_view < 1, all_in_view = 0; com and spread
  describe the UGVs that ARE seen.
- Frame present but nothing detected: frac_in_view = 0, com = (0.5, 0.5), spread = 0,
  edge_margin = 0 (neutral values that the zero fraction marks as meaningless).
- No frame at all (dropped, late, link lost): frame_ok = 0 and the same neutral values;
  altitude still comes from the autopilot's state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from skyherd.perception.camera import CameraParams, CameraPose, in_image, project

FEATURE_NAMES: tuple[str, ...] = (
    "com_u",
    "com_v",
    "spread",
    "altitude",
    "frac_in_view",
    "all_in_view",
    "edge_margin",
    "frame_ok",
)
N_FEATURES = len(FEATURE_NAMES)


@dataclass(frozen=True)
class FeatureParams:
    """Normalisation of φ(s)."""

    altitude_max_m: float = 60.0  # altitude that maps to 1.0 [m]


@dataclass(frozen=True)
class GroupMeasure:
    """What a frame says about the UGV group, in pixels.

    centroids_px  (K, 2) detected (or truly visible) UGV centres [px]
    n_expected    UGVs in the team
    com_px        (2,) mean of the centroids [px], None when K = 0
    circle_px     (2,) centre of the minimum enclosing circle [px], None when K = 0
    radius_px     its radius [px] (0 when K <= 1)
    """

    centroids_px: np.ndarray
    n_expected: int
    com_px: np.ndarray | None
    circle_px: np.ndarray | None
    radius_px: float

    @property
    def count(self) -> int:
        return int(self.centroids_px.shape[0])

    @property
    def all_in_view(self) -> bool:
        return self.n_expected > 0 and self.count >= self.n_expected


def spread_circle(points_px: np.ndarray) -> tuple[np.ndarray | None, float]:
    """Minimum enclosing circle of points (K, 2) [px] → (centre (2,), radius [px])."""
    k = points_px.shape[0]
    if k == 0:
        return None, 0.0
    if k == 1:
        return points_px[0].astype(float).copy(), 0.0
    (cu, cv), r = cv2.minEnclosingCircle(np.ascontiguousarray(points_px, dtype=np.float32))
    return np.array([cu, cv], dtype=float), float(r)


def measure_group(centroids_px: np.ndarray, n_expected: int) -> GroupMeasure:
    """Centre of mass and spread circle of UGV pixel centres (K, 2); non-finite rows dropped."""
    c = np.asarray(centroids_px, dtype=float).reshape(-1, 2)
    if not np.isfinite(c).all():
        c = c[np.isfinite(c).all(axis=1)]
    if c.shape[0] == 0:
        return GroupMeasure(c, int(n_expected), None, None, 0.0)
    centre, r = spread_circle(c)
    return GroupMeasure(c, int(n_expected), c.mean(axis=0), centre, r)


def features(
    m: GroupMeasure | None,
    altitude_m: float,
    cam: CameraParams,
    params: FeatureParams = FeatureParams(),
) -> np.ndarray:
    """φ(s) (8,) float64 in [0, 1] from a group measure; `m` None means no frame arrived."""
    phi = np.zeros(N_FEATURES)
    phi[0] = phi[1] = 0.5
    alt = float(altitude_m)
    phi[3] = min(max(alt / params.altitude_max_m, 0.0), 1.0) if math.isfinite(alt) else 0.0
    if m is None:
        return phi
    phi[7] = 1.0
    k = m.count
    if k == 0 or m.n_expected <= 0:
        return phi
    w, h = cam.width_px, cam.height_px
    phi[0] = min(max(0.5 + (m.com_px[0] - cam.cx) / w, 0.0), 1.0)
    phi[1] = min(max(0.5 + (m.com_px[1] - cam.cy) / h, 0.0), 1.0)
    phi[2] = min(m.radius_px / (0.5 * math.hypot(w, h)), 1.0)
    phi[4] = min(k / m.n_expected, 1.0)
    phi[5] = 1.0 if k >= m.n_expected else 0.0
    c = m.centroids_px
    edge = min(float(c.min()) + 0.5, w - 0.5 - float(c[:, 0].max()), h - 0.5 - float(c[:, 1].max()))
    phi[6] = min(max(edge / (0.5 * min(w, h)), 0.0), 1.0)
    return phi


def true_centroids(
    cam: CameraParams,
    pose: CameraPose,
    marker_points_ned: np.ndarray,
    detectable: np.ndarray | None = None,
    margin_px: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Fast path: the pixels a perfect detector would report.

    marker_points_ned (N, 3) NED [m] centres of the UGVs' top markers; detectable (N,) bool
    (False = camouflaged, a detector would miss it). Returns (uv (N, 2) [px], seen (N,) bool:
    in front of the camera, inside the image by `margin_px`, and detectable).
    """
    uv, _ = project(cam, pose, marker_points_ned)
    seen = in_image(cam, uv, margin_px)
    if detectable is not None:
        seen &= np.asarray(detectable, dtype=bool)
    return uv, seen


def features_from_truth(
    cam: CameraParams,
    pose: CameraPose,
    marker_points_ned: np.ndarray,
    altitude_m: float,
    detectable: np.ndarray | None = None,
    params: FeatureParams = FeatureParams(),
) -> np.ndarray:
    """φ(s) (8,) straight from the geometry (no pixels): the fast path for training."""
    uv, seen = true_centroids(cam, pose, marker_points_ned, detectable)
    m = measure_group(uv[seen], marker_points_ned.shape[0])
    return features(m, altitude_m, cam, params)
