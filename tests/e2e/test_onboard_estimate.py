"""No truth on the onboard side: the companion knows the camera's pose only from the autopilot's
estimate (MAVLink telemetry) composed with the camera's mount (hil.camera_mount), never from the
pose the simulator stamps in the frame's header.

- the composition against closed forms (level gimbal, body mount, pointed head);
- a frame whose header says one pose and whose telemetry says another: the companion follows
  the telemetry (Zenoh and MAVLink messages, no flight);
- `skyherd fly` under a baro offset and under a GPS offset: φ's altitude (decisions.jsonl) is
  the estimate's (metrics.csv, the companion's telemetry) and differs from the truth
  (world.csv) by the fault's size.
"""

import csv
import dataclasses
import json
import math

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.frames import euler_to_quat
from skyherd.flight.geo import DEFAULT_HOME, ned_to_geodetic
from skyherd.groundsim.ugv import UGVModel, initial_states
from skyherd.mission.onboard import CameraFrame, onboard_frame
from skyherd.mission.perception import Perception
from skyherd.mission.vehicle import VehicleLink
from skyherd.perception.camera import CameraParams, backproject_to_ground, project
from skyherd.perception.features import FeatureParams
from skyherd.perception.gimbal import ORBIT_CAMERA
from skyherd.perception.mount import MOUNTS, mounted_camera_pose
from skyherd.perception.render_fast import FastRenderer
from skyherd.perception.transport import camera_info, decode_frame, encode_frame
from skyherd.scripts.cli import main
from skyherd.task.params import TaskParams

CAM = CameraParams()
ALT_MAX = FeatureParams().altitude_max_m


# ---- the pose composition ----------------------------------------------------------------------
@pytest.mark.parametrize("yaw", [0.0, 0.7, -2.5, math.pi])
def test_level_gimbal_keeps_the_heading_and_looks_straight_down(yaw):
    """Level mount, any roll and pitch: the lens is the mount offset (0.1 m) straight below the
    vehicle, the optical axis is down, image right is the heading + 90°, image down is the
    heading + 180° (image top = forward)."""
    pos = np.array([12.0, -7.0, -23.0])
    q = euler_to_quat(0.3, -0.2, yaw)
    pose = mounted_camera_pose(CAM, "level", pos, q)
    np.testing.assert_allclose(pose.pos_ned, [12.0, -7.0, -23.0 + 0.1], atol=1e-12)
    c, s = math.cos(yaw), math.sin(yaw)
    r = pose.r_world_from_cam
    np.testing.assert_allclose(r[:, 0], [-s, c, 0.0], atol=1e-12)  # image right
    np.testing.assert_allclose(r[:, 1], [-c, -s, 0.0], atol=1e-12)  # image down
    np.testing.assert_allclose(r[:, 2], [0.0, 0.0, 1.0], atol=1e-12)  # optical axis
    # the point below the vehicle is at the image centre, at depth altitude − offset
    uv, depth = project(CAM, pose, np.array([12.0, -7.0, 0.0]))
    np.testing.assert_allclose(uv, CAM.centre_px, atol=1e-9)
    assert depth == pytest.approx(23.0 - 0.1)


def test_body_mount_rolls_with_the_vehicle():
    """Body-fixed, rolled by φ to the right at height h: the optical axis swings to the left,
    (0, −sin φ, cos φ), and the ground point below the vehicle is seen right of the centre by
    fx·h·sin φ / (h·cos φ − 0.1) (the lens 0.1 m down the body axis)."""
    roll, h = 0.2, 30.0
    pose = mounted_camera_pose(CAM, "body", np.array([0.0, 0.0, -h]), euler_to_quat(roll, 0, 0))
    np.testing.assert_allclose(pose.r_world_from_cam[:, 2], [0, -math.sin(roll), math.cos(roll)],
                               atol=1e-12)  # fmt: skip
    uv, _ = project(CAM, pose, np.array([0.0, 0.0, 0.0]))
    want = CAM.fx * h * math.sin(roll) / (h * math.cos(roll) - 0.1)
    assert uv == pytest.approx([CAM.cx + want, CAM.cy], abs=1e-9)


def test_pointed_head_puts_the_roi_at_the_image_centre_and_looks_down_without_one():
    pos, q = np.array([0.0, 93.0, -92.5]), euler_to_quat(0.4, 0.05, 1.0)
    roi = np.array([120.0, -40.0, 0.0])
    uv, _ = project(ORBIT_CAMERA, mounted_camera_pose(ORBIT_CAMERA, "pointed", pos, q, roi), roi)
    np.testing.assert_allclose(uv, ORBIT_CAMERA.centre_px, atol=1e-6)
    down = mounted_camera_pose(ORBIT_CAMERA, "pointed", pos, q)
    np.testing.assert_allclose(down.r_world_from_cam[:, 2], [0, 0, 1], atol=1e-12)
    with pytest.raises(ValueError, match="mount must be one of"):
        mounted_camera_pose(CAM, "gimballed", pos, q)
    assert MOUNTS == ("body", "level", "pointed")
    info = camera_info(ORBIT_CAMERA, "raw", "pointed")  # the camera announces how it is carried
    assert info["mount"] == "pointed" and info["fx_px"] == ORBIT_CAMERA.fx


# ---- a frame on the companion's side -----------------------------------------------------------
def _vehicle(pos_ned, yaw: float = 0.0, t_ms: int = 5000) -> VehicleLink:
    """A VehicleLink that has received the autopilot's telemetry at t_ms: HEARTBEAT, HOME_POSITION,
    LOCAL_POSITION_NED and ATTITUDE_QUATERNION, as bytes through a MAVLink parser."""
    enc, dec = M.MAVLink(None, srcSystem=1, srcComponent=1), M.MAVLink(None)
    lat, lon = DEFAULT_HOME.lat_deg, DEFAULT_HOME.lon_deg
    q = euler_to_quat(0.1, -0.05, yaw)
    msgs = [
        M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_PX4, 0, 0, 0, 3),
        M.MAVLink_home_position_message(
            round(lat * 1e7),
            round(lon * 1e7),
            round(DEFAULT_HOME.alt_m * 1000),
            0,
            0,
            0,
            [1, 0, 0, 0],
            0,
            0,
            0,
        ),  # fmt: skip
        M.MAVLink_local_position_ned_message(t_ms, *pos_ned, 0.0, 0.0, 0.0),
        M.MAVLink_attitude_quaternion_message(t_ms, *q, 0.0, 0.0, 0.0, [0, 0, 0, 0]),
    ]
    v = VehicleLink(link=None)
    for m in msgs:
        v.apply(dec.parse_char(m.pack(enc)))
    return v


def test_the_companion_frame_has_no_truth_and_follows_the_telemetry():
    """The simulator's header says 45 m; the autopilot's estimate says 20 m. The companion's
    frame carries the stamp, the pixels and the estimate — no field for the header's pose — and
    φ's altitude is 20 / 60."""
    task = TaskParams()
    team = initial_states(np.array([[4.0, 0.0], [-3.0, 3.0], [-3.0, -3.0]]))

    class Truth:
        pos_ned, quat = np.array([0.0, 0.0, -45.0]), np.array([1.0, 0.0, 0.0, 0.0])

    image = FastRenderer(task.camera, UGVModel()).render(Truth, team)
    wire = decode_frame(encode_frame(7, 5.0, Truth.pos_ned, Truth.quat, image))
    assert wire.pos_ned[2] == -45.0  # the header's truth is on the wire, for the records
    frame = onboard_frame(wire, _vehicle([0.0, 0.0, -20.0]))
    names = {f.name for f in dataclasses.fields(CameraFrame)}
    assert names == {"t", "seq", "image", "vehicle", "roi_ned"}
    assert not hasattr(frame, "pos_ned") and not hasattr(frame, "quat")
    assert frame.t == 5.0 and frame.seq == 7 and frame.altitude_m == pytest.approx(20.0, abs=1e-5)
    seen = Perception(task)
    seen.on_frame(5.0, frame, "ok")
    assert seen.phi[3] == pytest.approx(20.0 / ALT_MAX, abs=1e-7)
    assert seen.phi[5] == 1.0  # the pixels are the truth's: all three UGVs in view
    # no telemetry yet: no altitude (φ's altitude 0), never the header's
    seen.on_frame(5.1, onboard_frame(wire, None), "ok")
    assert seen.phi[3] == 0.0


def test_the_estimate_is_taken_at_the_frames_capture_time():
    """Telemetry at 4.9 s and 5.0 s (and 5.1 s, after the frame): a frame stamped 5.0 s gets the
    5.0 s sample, a frame stamped 4.95 s the 4.9 s one; one stamped before every sample (a
    camera clock behind the autopilot's) the nearest, the oldest; no telemetry, no pose."""
    v = _vehicle([0.0, 0.0, -10.0], t_ms=4900)
    enc, dec = M.MAVLink(None, srcSystem=1, srcComponent=1), M.MAVLink(None)
    for t_ms, alt in ((5000, 11.0), (5100, 12.0)):
        pos = M.MAVLink_local_position_ned_message(t_ms, 0.0, 0.0, -alt, 0, 0, 0)
        att = M.MAVLink_attitude_quaternion_message(t_ms, 1, 0, 0, 0, 0, 0, 0, [0] * 4)
        for m in (pos, att):
            v.apply(dec.parse_char(m.pack(enc)))
    assert -v.pose_at(5.0).pos_ned[2] == 11.0
    assert -v.pose_at(4.95).pos_ned[2] == 10.0
    assert -v.pose_at(4.8).pos_ned[2] == 10.0
    assert VehicleLink(link=None).pose_at(5.0) is None
    # a position that is not a number (an EKF without its origin: real ArduPlane's first
    # samples) is no estimate: no pose, never a NaN camera pose that aborts the orbit
    nan = float("nan")
    pos = M.MAVLink_local_position_ned_message(5200, nan, nan, nan, 0, 0, 0)
    att = M.MAVLink_attitude_quaternion_message(5200, 1, 0, 0, 0, 0, 0, 0, [0] * 4)
    for m in (pos, att):
        v.apply(dec.parse_char(m.pack(enc)))
    assert v.pose_at(5.2) is None and -v.pose_at(5.1).pos_ned[2] == 12.0


def test_a_gps_offset_moves_what_the_companion_sees_on_the_ground_by_the_offset():
    """A frame rendered from the true pose, back-projected through the pose the companion has
    (the estimate, 3 m north and 2 m west of the truth): every UGV lands 3 m north and 2 m west
    of where it is. The companion sees the world through its estimate, as a real one does."""
    task = TaskParams()
    ugvs = np.array([[4.0, 0.0], [-3.0, 3.0], [-3.0, -3.0]])
    team = initial_states(ugvs)
    truth = np.array([0.0, 0.0, -25.0])
    yaw = 0.4
    level = type("P", (), {"pos_ned": truth, "quat": euler_to_quat(0.0, 0.0, yaw)})
    image = FastRenderer(task.camera, UGVModel()).render(level, team)
    wire = decode_frame(encode_frame(1, 5.0, truth, level.quat, image))
    frame = onboard_frame(wire, _vehicle(truth + [3.0, -2.0, 0.0], yaw=yaw))
    det = Perception(task).detector.detect(frame.image)
    ground = backproject_to_ground(task.camera, frame.camera_pose(task.camera, "level"),
                                   det.centroids_px, -UGVModel().marker_top_m)  # fmt: skip
    got = sorted(map(tuple, np.round(ground[:, :2], 1)))
    want = sorted(map(tuple, np.round(ugvs + [3.0, -2.0], 1)))
    np.testing.assert_allclose(got, want, atol=0.15)


def test_the_gimbal_roi_counts_once_acknowledged_as_the_gimbal_decodes_it():
    v = _vehicle([0.0, 0.0, -20.0])
    sent = []
    v.send = sent.append
    roi = np.array([120.3, -40.7, 0.0])
    assert v.point_gimbal(roi) and v.roi_ned is None  # not yet acknowledged
    (cmd,) = sent
    assert (cmd.command, cmd.target_component) == (M.MAV_CMD_DO_SET_ROI_LOCATION,
                                                   M.MAV_COMP_ID_GIMBAL)  # fmt: skip
    lat, lon, _ = ned_to_geodetic(DEFAULT_HOME, roi)
    assert (cmd.param5, cmd.param6) == (lat, lon)
    enc, dec = M.MAVLink(None, srcSystem=1, srcComponent=M.MAV_COMP_ID_GIMBAL), M.MAVLink(None)
    ack = M.MAVLink_command_ack_message(M.MAV_CMD_DO_SET_ROI_LOCATION, M.MAV_RESULT_ACCEPTED,
                                       0, 0, 1, 191)  # fmt: skip
    v.apply(dec.parse_char(ack.pack(enc)))
    np.testing.assert_allclose(v.roi_ned, roi, atol=1.0)  # float32 latitude: ~1 m
    v.point_gimbal(np.array([0.0, 0.0, 0.0]))
    denied = M.MAVLink_command_ack_message(M.MAV_CMD_DO_SET_ROI_LOCATION, M.MAV_RESULT_DENIED,
                                           0, 0, 1, 191)  # fmt: skip
    v.apply(dec.parse_char(denied.pack(enc)))
    np.testing.assert_allclose(v.roi_ned, roi, atol=1.0)  # a denied ROI changes nothing


# ---- `skyherd fly` under an estimate fault -----------------------------------------------------
def _rows(path, key="t"):
    return {round(float(r[key]), 3): r for r in csv.DictReader(open(path))}


def _altitudes(run):
    """Per decision time: (φ's altitude, the estimate's, the truth's) [m]."""
    est, truth = _rows(run / "metrics.csv"), _rows(run / "world.csv")
    out = {}
    for line in (run / "decisions.jsonl").read_text().splitlines():
        d = json.loads(line)
        t = round(d["t"], 3)
        out[t] = (d["phi"][3] * ALT_MAX, -float(est[t]["down"]), -float(truth[t]["down"]))
    return out


@pytest.mark.parametrize(
    "fault,offset_up_m",
    [("baro@12:5:5", 5.0), ("gps_glitch@12:2,0,-4:5", 4.0)],
    ids=["baro", "gps"],
)
@pytest.mark.slow
def test_phi_follows_the_estimate_not_the_truth_under_an_estimate_fault(
    tmp_path, fault, offset_up_m
):
    """The fault from 12 s to 17 s of an AI phase from 10 s to 18 s: at every decision φ's
    altitude is the estimate's (to φ's 6-digit rounding: 60 µm, and the telemetry's float32);
    in the fault it is `offset_up_m` above the truth, outside it equal to the truth."""
    args = ["fly", "--duration", "8", "--fault", fault, "--speedup", "0", "--instance", "31",
            "--zenoh-port", "7473", "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    alts = _altitudes(run)
    inside = [t for t in alts if 12.0 <= t < 17.0]
    outside = [t for t in alts if t < 12.0 or t >= 17.0]
    assert len(inside) >= 9 and len(outside) >= 4, sorted(alts)
    for t, (phi_alt, est, true) in alts.items():
        assert phi_alt == pytest.approx(est, abs=1e-3), t
        want = offset_up_m if t in inside else 0.0
        assert est - true == pytest.approx(want, abs=1e-3), t
        assert abs(phi_alt - true - want) < 2e-3, t
