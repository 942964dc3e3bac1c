"""Detector accuracy against ground truth over random scenes (used by tests and the bench).

A scene: the UAV at 10–45 m with roll/pitch up to ±0.3 rad and any heading; N UGVs placed
so that their markers project inside the image (by `margin_px`) and at least `min_sep_px`
apart, with random headings. Truth is the projection of each marker's centre
(`perception.features.true_centroids`); a detection is matched to the nearest truth
(Hungarian assignment on pixel distance).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from skyherd.flight.frames import euler_to_quat
from skyherd.groundsim.ugv import UGVModel, UGVStates, marker_points_ned
from skyherd.perception.camera import CameraParams, UAVPose, backproject_to_ground, camera_pose
from skyherd.perception.detector import Detector
from skyherd.perception.features import measure_group, true_centroids


@dataclass(frozen=True)
class SceneParams:
    n_ugv: int = 3
    alt_range_m: tuple[float, float] = (10.0, 45.0)
    tilt_max_rad: float = 0.3  # roll and pitch drawn from ±this
    margin_px: float = 12.0  # markers at least this far inside the image
    min_sep_px: float = 20.0  # marker centres at least this far apart in the image (and at
    # least 1.5 marker widths + 3 px, so that the markers are apart)


def random_scene(
    cam: CameraParams,
    model: UGVModel,
    sp: SceneParams,
    rng: np.random.Generator,
    max_tries: int = 10000,
) -> tuple[UAVPose, UGVStates]:
    """One random scene (UAV pose, UGV states) satisfying `sp` (ValueError if none is found)."""
    for _ in range(max_tries):
        alt = rng.uniform(*sp.alt_range_m)
        r, p = rng.uniform(-sp.tilt_max_rad, sp.tilt_max_rad, 2)
        uav = UAVPose(
            np.array([rng.uniform(-50, 50), rng.uniform(-50, 50), -alt]),
            euler_to_quat(r, p, rng.uniform(-np.pi, np.pi)),
        )
        pose = camera_pose(cam, uav.pos_ned, uav.quat)
        uv = np.c_[
            rng.uniform(sp.margin_px, cam.width_px - 1 - sp.margin_px, sp.n_ugv),
            rng.uniform(sp.margin_px, cam.height_px - 1 - sp.margin_px, sp.n_ugv),
        ]
        d = np.hypot(*(uv[:, None, :] - uv[None, :, :]).transpose(2, 0, 1))
        # "Apart": marker diagonals (√2 · side, ~1.5 with tilt) plus a 3 px gap.
        sep = max(sp.min_sep_px, 1.5 * cam.fx * model.marker_size_m / alt + 3.0)
        if sp.n_ugv > 1 and d[np.triu_indices(sp.n_ugv, 1)].min() < sep:
            continue
        # Place each marker top on the ray through its pixel, then the hull below it.
        ground = backproject_to_ground(cam, pose, uv, ground_down_m=-model.marker_top_m)
        if not np.isfinite(ground).all():
            continue
        states = UGVStates(
            ground[:, :2].copy(), rng.uniform(-np.pi, np.pi, sp.n_ugv), np.zeros(sp.n_ugv)
        )
        return uav, states
    raise ValueError(f"no scene fits {sp} in this camera: lower n_ugv, min_sep_px or margin_px")


@dataclass(frozen=True)
class AccuracyReport:
    """Per-frame errors [px]: centroid (per matched UGV), centre of mass, spread radius."""

    centroid_err: np.ndarray
    com_err: np.ndarray
    radius_err: np.ndarray
    count_ok: np.ndarray  # (frames,) bool: detected count == true count

    def summary(self) -> dict[str, float]:
        return {
            "frames": int(self.count_ok.size),
            "centroid_median_px": float(np.median(self.centroid_err)),
            "centroid_p95_px": float(np.percentile(self.centroid_err, 95)),
            "com_median_px": float(np.median(self.com_err)),
            "radius_median_px": float(np.median(self.radius_err)),
            "radius_p95_px": float(np.percentile(self.radius_err, 95)),
            "count_exact": float(self.count_ok.mean()),
        }


def evaluate(
    renderer,
    detector: Detector,
    cam: CameraParams,
    model: UGVModel,
    n_frames: int,
    rng: np.random.Generator,
    sp: SceneParams | None = None,
    progress=None,
) -> AccuracyReport:
    """Render `n_frames` random scenes, detect, compare with the projected truth."""
    sp = sp if sp is not None else SceneParams()
    cerr, merr, rerr, ok = [], [], [], []
    for _ in range(n_frames):
        uav, states = random_scene(cam, model, sp, rng)
        frame = renderer.render(uav, states)
        det = detector.detect(frame)
        pose = camera_pose(cam, uav.pos_ned, uav.quat)
        uv, _ = true_centroids(cam, pose, marker_points_ned(states, model))
        truth = measure_group(uv, sp.n_ugv)
        ok.append(det.count == sp.n_ugv)
        if det.count:
            cost = np.hypot(*(det.centroids_px[:, None, :] - uv[None, :, :]).transpose(2, 0, 1))
            ri, ci = linear_sum_assignment(cost)
            cerr.extend(cost[ri, ci].tolist())
            merr.append(float(np.hypot(*(det.measure.com_px - truth.com_px))))
        else:
            merr.append(np.inf)
        rerr.append(abs(det.measure.radius_px - truth.radius_px))
        if progress is not None:
            progress.update(1)
    return AccuracyReport(np.array(cerr), np.array(merr), np.array(rerr), np.array(ok))
