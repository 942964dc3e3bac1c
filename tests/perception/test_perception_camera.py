"""Camera geometry and the feature vector φ(s): closed-form checks."""

import math

import numpy as np
import pytest

from skyherd.flight.frames import euler_to_quat
from skyherd.perception.camera import (
    CameraParams,
    backproject_to_ground,
    camera_pose,
    footprint_ned,
    in_image,
    project,
)
from skyherd.perception.features import (
    FEATURE_NAMES,
    FeatureParams,
    features,
    features_from_truth,
    measure_group,
)

CAM = CameraParams(mount_offset_frd=(0.0, 0.0, 0.0))


def level_pose(alt=30.0, yaw=0.0, n=0.0, e=0.0, roll=0.0, pitch=0.0):
    return camera_pose(CAM, np.array([n, e, -alt]), euler_to_quat(roll, pitch, yaw))


def test_point_below_is_image_centre_and_axes():
    pose = level_pose()
    uv, z = project(CAM, pose, np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    assert np.allclose(uv[0], [CAM.cx, CAM.cy])
    assert math.isclose(z[0], 30.0)
    f = CAM.fx
    # north (body forward, heading 0) is image up; east (body right) is image right
    assert np.allclose(uv[1], [CAM.cx, CAM.cy - f / 30.0])
    assert np.allclose(uv[2], [CAM.cx + f / 30.0, CAM.cy])


def test_focal_length_and_footprint_closed_form():
    assert math.isclose(CAM.fx, 160.0 / math.tan(math.radians(35.0)))
    fp = footprint_ned(CAM, level_pose(alt=30.0))
    half_w = 30.0 * math.tan(math.radians(35.0))  # east half-width [m]
    half_h = half_w * 240 / 320
    # top-left corner of the image = forward (north) and left (west)
    assert np.allclose(fp[0], [half_h, -half_w])
    assert np.allclose(fp[2], [-half_h, half_w])
    # footprint doubles with altitude
    assert np.allclose(footprint_ned(CAM, level_pose(alt=60.0)), 2 * fp)


def test_yaw_rotates_image_and_roll_shifts_it():
    # heading east: a point to the east is image up
    uv, _ = project(CAM, level_pose(yaw=math.pi / 2), np.array([0.0, 5.0, 0.0]))
    assert uv[0] == pytest.approx(CAM.cx) and uv[1] < CAM.cy
    # roll right 10 deg: the belly (camera) turns to the left (west), the point below moves right
    pose = level_pose(roll=math.radians(10))
    uv, _ = project(CAM, pose, np.zeros(3))
    assert uv[0] == pytest.approx(CAM.cx + CAM.fx * math.tan(math.radians(10)))
    assert uv[1] == pytest.approx(CAM.cy)


def test_backproject_inverts_project_any_attitude():
    rng = np.random.default_rng(0)
    for _ in range(50):
        r, p = rng.uniform(-0.4, 0.4, 2)
        pose = level_pose(alt=rng.uniform(5, 60), yaw=rng.uniform(-3, 3), roll=r, pitch=p)
        pts = np.c_[rng.uniform(-20, 20, (10, 2)), np.zeros(10)]
        uv, z = project(CAM, pose, pts)
        ok = z > 0  # a far point can lie behind a tilted camera
        back = backproject_to_ground(CAM, pose, uv[ok])
        assert np.allclose(back, pts[ok], atol=1e-9)
        assert np.isnan(uv[~ok]).all()


def test_behind_camera_is_nan_and_not_in_image():
    pose = level_pose(alt=10)
    uv, z = project(CAM, pose, np.array([[0.0, 0.0, -20.0]]))  # 10 m above the UAV
    assert z[0] < 0 and np.isnan(uv).all()
    assert not in_image(CAM, uv)[0]


def test_mount_pitch_tilts_forward():
    cam = CameraParams(mount_pitch_rad=math.radians(20), mount_offset_frd=(0, 0, 0))
    pose = camera_pose(cam, np.array([0.0, 0.0, -10.0]), euler_to_quat(0, 0, 0))
    ahead = np.array([10 * math.tan(math.radians(20)), 0.0, 0.0])
    uv, _ = project(cam, pose, ahead)
    assert np.allclose(uv, [cam.cx, cam.cy])


def test_features_cases():
    fp = FeatureParams(altitude_max_m=60.0)
    m = measure_group(np.array([[CAM.cx, CAM.cy - 50], [CAM.cx, CAM.cy + 50]]), 2)
    phi = features(m, 30.0, CAM, fp)
    assert len(phi) == len(FEATURE_NAMES) == 8
    assert phi[0] == pytest.approx(0.5) and phi[1] == pytest.approx(0.5)
    assert phi[2] == pytest.approx(50.0 / 200.0, abs=1e-3)  # half-diagonal of 320x240 = 200
    assert phi[3] == pytest.approx(0.5)
    assert phi[4] == 1.0 and phi[5] == 1.0 and phi[7] == 1.0
    assert phi[6] == pytest.approx((CAM.cy - 50 + 0.5) / 120.0)
    # one of three missing (camouflaged / out of view)
    m = measure_group(np.array([[10.0, 10.0], [20.0, 10.0]]), 3)
    phi = features(m, 30.0, CAM, fp)
    assert phi[4] == pytest.approx(2 / 3) and phi[5] == 0.0 and phi[7] == 1.0
    assert phi[0] < 0.1 and phi[1] < 0.1
    # frame but nothing seen; no frame at all
    empty = features(measure_group(np.zeros((0, 2)), 3), 30.0, CAM, fp)
    none = features(None, 30.0, CAM, fp)
    assert list(empty) == [0.5, 0.5, 0, 0.5, 0, 0, 0, 1]
    assert list(none) == [0.5, 0.5, 0, 0.5, 0, 0, 0, 0]
    # bad input: NaN altitude and NaN centroids never crash, never leave [0, 1]
    phi = features(measure_group(np.array([[np.nan, 1.0], [5.0, 5.0]]), 2), math.nan, CAM, fp)
    assert np.all((phi >= 0) & (phi <= 1)) and phi[4] == 0.5


def test_features_from_truth_hidden_and_out_of_view():
    pose = level_pose(alt=20.0)
    pts = np.array([[0.0, 0.0, -0.5], [3.0, 3.0, -0.5], [200.0, 0.0, -0.5]])
    phi = features_from_truth(CAM, pose, pts, 20.0)
    assert phi[4] == pytest.approx(2 / 3) and phi[5] == 0.0
    phi = features_from_truth(CAM, pose, pts[:2], 20.0, detectable=np.array([True, False]))
    assert phi[4] == 0.5 and phi[2] == 0.0
    phi = features_from_truth(CAM, pose, pts[:2], 20.0)
    assert phi[5] == 1.0 and phi[0] > 0.5 and phi[1] < 0.5  # north-east: right and up


def test_camera_rig_rate_and_features():
    from skyherd.groundsim.ugv import UGVStates
    from skyherd.perception.camera import UAVPose
    from skyherd.perception.pipeline import CameraRig, CameraRigParams

    rig = CameraRig(CameraParams(), 3, CameraRigParams(rate_hz=10.0))
    uav = UAVPose(np.array([0.0, 0.0, -30.0]), euler_to_quat(0, 0, 0))
    st = UGVStates(np.array([[0.0, 0.0], [4.0, 0.0], [0.0, 4.0]]), np.zeros(3), np.zeros(3))
    ticks = [rig.tick(k * 0.02, uav, st) for k in range(100)]  # 2 s at 50 Hz
    got = [tk for tk in ticks if tk is not None]
    assert len(got) == 20 and got[1].t == pytest.approx(0.1)
    phi = got[-1].phi
    assert phi[4] == 1.0 and phi[5] == 1.0 and phi[3] == pytest.approx(0.5)
    assert got[-1].detections.count == 3
    with pytest.raises(ValueError, match="GroundWorld"):
        CameraRig(CameraParams(), 3, CameraRigParams(renderer="bullet"))


def test_non_finite_pose_is_refused_and_rig_skips_the_frame():
    from skyherd.groundsim.ugv import UGVStates
    from skyherd.perception.camera import UAVPose
    from skyherd.perception.pipeline import CameraRig
    from skyherd.perception.render_fast import FastRenderer

    st = UGVStates(np.zeros((3, 2)), np.zeros(3), np.zeros(3))
    bad = UAVPose(np.array([0.0, np.nan, -30.0]), euler_to_quat(0, 0, 0))
    with pytest.raises(ValueError, match="finite"):
        FastRenderer(CAM).render(bad, st)
    with pytest.raises(ValueError, match="unit length"):
        FastRenderer(CAM).render(UAVPose(np.array([0.0, 0, -30]), np.array([2.0, 0, 0, 0])), st)
    rig = CameraRig(CAM, 3)
    assert rig.tick(0.0, bad, st) is None and rig.bad_poses == 1
    good = UAVPose(np.array([0.0, 0.0, -30.0]), euler_to_quat(0, 0, 0))
    assert rig.tick(0.1, good, st) is not None


def test_slightly_non_unit_quaternion_is_normalised():
    q = euler_to_quat(0.1, 0.2, 0.3)
    pts = np.array([[3.0, 4.0, 0.0]])
    a, _ = project(CAM, camera_pose(CAM, np.array([0, 0, -20.0]), q), pts)
    b, _ = project(CAM, camera_pose(CAM, np.array([0, 0, -20.0]), 1.01 * q), pts)
    assert np.allclose(a, b, atol=1e-9)
