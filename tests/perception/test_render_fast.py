"""The fast renderer: its one-pass geometry draws the same pixels as drawing each UGV's hull and
marker on its own (the renderer before issue 31's cut, kept here as the reference)."""

import cv2
import numpy as np
import pytest

from skyherd.groundsim.ugv import (
    BODY_RGB,
    GROUND_RGB,
    MARKER_COLOURS,
    UGVModel,
    UGVStates,
    corners_ned,
    marker_corners_ned,
)
from skyherd.perception.camera import CameraParams, UAVPose, camera_pose, project
from skyherd.perception.render_fast import FastRenderer

CAMERAS = (CameraParams(), CameraParams(width_px=640, height_px=480, mount_pitch_rad=0.3))


def reference_hull_corners(states: UGVStates, m: UGVModel) -> np.ndarray:
    c, s = np.cos(states.heading), np.sin(states.heading)
    fwd, right = np.stack([c, s], -1), np.stack([-s, c], -1)
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=float)
    ne = states.pos_ne[:, None, :] + (
        0.5 * m.length_m * signs[None, :, 0:1] * fwd[:, None, :]
        + 0.5 * m.width_m * signs[None, :, 1:2] * right[:, None, :]
    )
    out = np.empty((states.n, 8, 3))
    out[:, :4, :2], out[:, 4:, :2] = ne, ne
    out[:, :4, 2], out[:, 4:, 2] = 0.0, -m.height_m
    return out


def reference_marker_corners(states: UGVStates, m: UGVModel) -> np.ndarray:
    h = 0.5 * m.marker_size_m
    c, s = np.cos(states.heading), np.sin(states.heading)
    fwd, right = np.stack([c, s], axis=-1), np.stack([-s, c], axis=-1)
    signs = np.array([[1, 1], [1, -1], [-1, -1], [-1, 1]], dtype=float)
    ne = states.pos_ne[:, None, :] + h * (
        signs[None, :, 0:1] * fwd[:, None, :] + signs[None, :, 1:2] * right[:, None, :]
    )
    out = np.empty((states.n, 4, 3))
    out[..., :2] = ne
    out[..., 2] = -m.marker_top_m
    return out


def reference_render(cam: CameraParams, m: UGVModel, uav, states: UGVStates) -> np.ndarray:
    """Each UGV's hull, then each marker, projected, checked and drawn one by one."""
    pose = camera_pose(cam, uav.pos_ned, uav.quat)
    img = np.empty((cam.height_px, cam.width_px, 3), np.uint8)
    img[:] = GROUND_RGB
    hull_uv, hz = project(cam, pose, reference_hull_corners(states, m))
    mark_uv, mz = project(cam, pose, reference_marker_corners(states, m))
    lim = 4.0 * (cam.width_px + cam.height_px)
    for i in range(states.n):
        if (hz[i] > cam.near_m).all() and np.abs(hull_uv[i] - cam.centre_px).max() < lim:
            pts = np.round(hull_uv[i] * 16.0).astype(np.int32)
            cv2.fillConvexPoly(img, cv2.convexHull(pts), BODY_RGB, cv2.LINE_AA, 4)
    for i in range(states.n):
        if (mz[i] > cam.near_m).all() and np.abs(mark_uv[i] - cam.centre_px).max() < lim:
            colour = GROUND_RGB if states.camouflaged[i] else MARKER_COLOURS[i % 6]
            pts = np.round(mark_uv[i] * 16.0).astype(np.int32)
            cv2.fillConvexPoly(img, pts, colour, cv2.LINE_AA, 4)
    return img


def random_scene(rng: np.random.Generator, n: int):
    """A team of n within ±40 m seen from anywhere up to 80 m high at any attitude (UGVs behind
    the camera, partly or far out of the image included)."""
    states = UGVStates(rng.uniform(-40, 40, (n, 2)), rng.uniform(-4, 4, n), rng.uniform(0, 3, n),
                       rng.random(n) < 0.3)  # fmt: skip
    q = rng.normal(size=4)
    q[0] += 3 * rng.random()  # mostly near level, sometimes far from it
    uav = UAVPose(
        np.array([*rng.uniform(-30, 30, 2), -rng.uniform(0.2, 80)]), q / np.linalg.norm(q)
    )
    return uav, states


def test_corners_are_the_hull_and_marker_corners():
    """groundsim.ugv.corners_ned (what the renderer projects) gives, to the bit, the hull and
    marker corners of each UGV computed on their own."""
    rng = np.random.default_rng(3)
    m = UGVModel(length_m=1.3, width_m=0.9, height_m=0.5, marker_size_m=0.8)
    for n in range(7):
        _, states = random_scene(rng, n)
        got = corners_ned(states, m)
        assert np.array_equal(got[:, :8], reference_hull_corners(states, m))
        assert np.array_equal(got[:, 8:], reference_marker_corners(states, m))
        assert np.array_equal(marker_corners_ned(states, m), reference_marker_corners(states, m))


@pytest.mark.parametrize("cam", CAMERAS)
def test_render_draws_what_each_ugv_drawn_alone_draws(cam):
    rng = np.random.default_rng(4)
    m = UGVModel()
    r = FastRenderer(cam, m)
    out = np.empty((cam.height_px, cam.width_px, 3), np.uint8)
    drawn = 0
    for k in range(600):
        uav, states = random_scene(rng, int(rng.integers(0, 7)))
        want = reference_render(cam, m, uav, states)
        got = r.render(uav, states, out if k % 2 else None)
        assert np.array_equal(got, want), k
        drawn += bool((want != want[0, 0]).any())
    assert drawn > 100  # the comparison saw UGVs, not only empty fields
