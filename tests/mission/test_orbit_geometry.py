"""The fixed-wing orbit's geometry in closed form, the stabilised gimbal, and what the camera
sees from the planned orbit (rendered pixels, the detector)."""

import math

import numpy as np
import pytest

from skyherd.flight.frames import euler_to_quat, quat_to_dcm
from skyherd.flight.geo import GRAVITY
from skyherd.groundsim.ugv import UGVStates
from skyherd.mission.orbit_plan import (
    ORBIT_CAMERA,
    OrbitParams,
    camera_radius,
    circle_certified,
    plan_orbit,
    turn_radius,
)
from skyherd.perception.camera import CameraParams, camera_pose, in_image, project
from skyherd.perception.gimbal import dcm_to_quat, gimbal_pose, look_at
from skyherd.perception.pipeline import CameraRig
from skyherd.safety.config import ENVELOPE_DIR, load_envelope


def test_turn_radius_matches_the_autopilots_hold_circle():
    # docs/fixedwing.md: HOLD radius V_trim² / (g tan(0.7 FW_R_LIM)) = 129 m at 24 m/s, 35°
    r = turn_radius(24.0, 0.7 * math.radians(35.0))
    assert r == pytest.approx(24.0**2 / (GRAVITY * math.tan(math.radians(24.5))), rel=1e-12)
    assert r == pytest.approx(129.0, abs=0.5)


def test_plan_closed_form():
    p = OrbitParams(team_speed_mps=2.0, team_radius_m=9.0, alt_min_m=40.0, alt_max_m=300.0)
    plan = plan_orbit(p)
    r = (24.0 + 2.0) ** 2 / (GRAVITY * math.tan(0.7 * math.radians(35.0)))  # (1)
    assert plan.radius_m == pytest.approx(r, rel=1e-12)
    assert plan.altitude_m == pytest.approx(r, rel=1e-12)  # h = R inside the band
    assert plan.depression_rad == pytest.approx(math.pi / 4, abs=1e-12)
    assert plan.slant_m == pytest.approx(math.sqrt(2) * r, rel=1e-12)
    f = ORBIT_CAMERA.fx
    assert plan.marker_px == pytest.approx(f / (2 * r), rel=1e-12)  # (2) at h = R
    assert plan.extent_m == pytest.approx(2 * 9.0 * 2 / 3, rel=1e-12)  # 2r(n−1)/n
    assert plan.team_px == pytest.approx(f * 12.0 / (math.sqrt(2) * r - 12.0), rel=1e-12)  # (3)
    # the steady bank about a still centre is below the planning bank (reserve for s)
    assert plan.bank_rad == pytest.approx(math.atan(24.0**2 / (GRAVITY * r)), rel=1e-12)
    assert plan.bank_rad < 0.7 * math.radians(35.0)


def test_a_steep_bank_limit_is_not_the_orbits_bank_the_camera_sets_the_circle():
    """ArduPlane's stock ROLL_LIMIT_DEG 65: the turn at 0.7 · 65° is a 55 m circle, too small
    for the camera to hold a 25 m team (173 px > 96 px); the plan widens it to the smallest
    circle (3) holds on and commands the shallower bank that flies it."""
    p = OrbitParams(airspeed_mps=22.0, bank_max_rad=math.radians(65.0), team_speed_mps=1.5,
                    team_radius_m=9.375, alt_min_m=40.0, alt_max_m=125.0, radius_max_m=189.0)  # fmt: skip
    r_turn = turn_radius(23.5, 0.7 * math.radians(65.0))
    plan = plan_orbit(p)
    f, rho = ORBIT_CAMERA.fx, 12.5
    d_min = rho * (1 + f / plan.team_px_max)  # (3) as a bound on the slant range
    assert r_turn < 60.0 < plan.radius_m
    assert plan.slant_m == pytest.approx(d_min, rel=1e-6)  # the smallest circle that fits
    assert plan.radius_m == pytest.approx(d_min / math.sqrt(2), rel=1e-6) == plan.altitude_m
    assert plan.team_px <= plan.team_px_max + 1e-9
    bank = math.atan(23.5**2 / (GRAVITY * plan.radius_m))
    assert plan.bank_cmd_rad == pytest.approx(bank, rel=1e-12)
    assert math.radians(31.0) < plan.bank_cmd_rad < 0.7 * math.radians(65.0)
    # where the turn's circle already fits, the plan is the turn's, as before
    same = plan_orbit(OrbitParams())
    assert same.radius_m == turn_radius(27.0, 0.7 * math.radians(35.0))
    assert same.bank_cmd_rad == pytest.approx(0.7 * math.radians(35.0), rel=1e-12)
    # below the band: h = alt_min and R from D² = R² + h²; above it: h = alt_max
    assert camera_radius(50.0, 40.0, 125.0) == pytest.approx(30.0)
    assert camera_radius(200.0, 40.0, 125.0) == pytest.approx(math.sqrt(200**2 - 125**2))
    assert camera_radius(30.0, 40.0, 125.0) == 0.0


def test_h_equal_r_maximises_the_marker_size():
    r = 150.0
    h = np.linspace(20.0, 600.0, 2901)
    px = ORBIT_CAMERA.fx * h / (r * r + h * h)
    assert h[np.argmax(px)] == pytest.approx(r, abs=0.3)


def test_altitude_clamped_to_the_envelope_band():
    plan = plan_orbit(OrbitParams(alt_min_m=40.0, alt_max_m=135.0))
    assert plan.radius_m > 135.0 and plan.altitude_m == 135.0


def test_plan_refuses_what_the_camera_cannot_hold():
    with pytest.raises(ValueError, match="does not fit"):  # the circle it needs is too wide
        plan_orbit(OrbitParams(team_radius_m=40.0, radius_max_m=189.0))
    with pytest.raises(ValueError, match="too small"):  # widened to fit: markers too small
        plan_orbit(OrbitParams(team_radius_m=40.0))
    with pytest.raises(ValueError, match="wider than"):  # the turn alone exceeds the hold
        plan_orbit(OrbitParams(bank_max_rad=math.radians(15.0), radius_max_m=189.0))
    with pytest.raises(ValueError, match="too small"):
        plan_orbit(OrbitParams(), CameraParams(hfov_rad=math.radians(70.0)))
    for bad in (dict(airspeed_mps=math.nan), dict(bank_max_rad=2.0), dict(alt_min_m=200.0)):
        with pytest.raises(ValueError):
            OrbitParams(**bad)


def test_dcm_to_quat_round_trip():
    rng = np.random.default_rng(0)
    for _ in range(200):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        r = quat_to_dcm(q)
        assert np.allclose(quat_to_dcm(dcm_to_quat(r)), r, atol=1e-12)


def test_gimbal_centres_the_target_with_a_level_image_whatever_the_bank():
    rng = np.random.default_rng(1)
    cam = ORBIT_CAMERA
    for _ in range(100):
        uav = np.array([*rng.uniform(-300, 300, 2), -rng.uniform(40, 150)])
        tgt = np.array([*rng.uniform(-300, 300, 2), 0.0])
        gp = gimbal_pose(cam, uav, rng.uniform(-math.pi, math.pi), tgt)
        pose = camera_pose(cam, gp.pos_ned, gp.quat)
        assert np.allclose(pose.pos_ned, uav, atol=1e-9)  # lens at the aircraft
        uv, z = project(cam, pose, tgt)
        assert np.allclose(uv, cam.centre_px, atol=1e-6) and z > 0
        assert abs(pose.r_world_from_cam[2, 0]) < 1e-12  # image x horizontal: no roll
        d = tgt - uav
        assert gp.tilt_rad == pytest.approx(math.atan2(d[2], math.hypot(d[0], d[1])))
    # straight down: the pan falls back to the heading (image top = forward)
    r, tilt, pan = look_at(np.array([0, 0, -100.0]), np.zeros(3), heading=0.5)
    assert tilt == pytest.approx(math.pi / 2) and pan == 0.5
    with pytest.raises(ValueError):
        look_at(np.array([0, 0, math.nan]), np.zeros(3), 0.0)


def _team(centre, radius, n=3):
    a = 2 * math.pi * np.arange(n) / n + 0.3
    pos = np.column_stack([centre[0] + radius * np.cos(a), centre[1] + radius * np.sin(a)])
    return UGVStates(pos, np.zeros(n), np.zeros(n), np.zeros(n, dtype=bool))


def test_every_ugv_detected_all_round_the_orbit_gimballed_not_body_fixed():
    """Pixels: from 36 points of the planned orbit, banked as the aircraft flies it, the
    gimballed camera's frames show the whole 10 m team to the detector; the same camera fixed
    to the body sees none of it (its axis meets the ground h·tan φ inward, not R)."""
    plan = plan_orbit(OrbitParams())
    r, h = plan.radius_m, plan.altitude_m
    team = _team((40.0, -25.0), 10.0)
    com = np.array([*team.pos_ne.mean(axis=0), 0.0])
    rig = CameraRig(ORBIT_CAMERA, 3)
    body_seen = 0
    for k, a in enumerate(np.linspace(0, 2 * math.pi, 36, endpoint=False)):
        uav = np.array([com[0] + r * math.cos(a), com[1] + r * math.sin(a), -h])
        heading = a + math.pi / 2  # clockwise orbit: course tangent
        q = euler_to_quat(plan.bank_rad, 0.03, heading)
        gp = gimbal_pose(ORBIT_CAMERA, uav, heading, com)
        tick = rig.tick(0.1 * k, gp, team)
        assert tick is not None
        assert len(tick.detections.centroids_px) == 3 and tick.phi[5] == 1.0
        pts = np.column_stack([team.pos_ne, np.zeros(3)])
        body = camera_pose(ORBIT_CAMERA, uav, q)
        body_seen += int(in_image(ORBIT_CAMERA, project(ORBIT_CAMERA, body, pts)[0]).all())
    assert body_seen == 0
    # closed form: the body axis meets the ground h·tan(bank) from below the aircraft, « R
    assert h * math.tan(plan.bank_rad) < 0.5 * r


def test_orbit_circle_certified_against_the_fence():
    spec, _ = load_envelope(ENVELOPE_DIR / "fixedwing_field.toml")
    geo = spec.geometry()
    assert circle_certified(geo, np.zeros(2), 150.0, 100.0, 10.0)
    assert not circle_certified(geo, np.array([900.0, 0.0]), 150.0, 100.0, 10.0)  # past the edge
    assert not circle_certified(geo, np.array([-500.0, 400.0]), 150.0, 100.0, 10.0)  # the tower
    assert not circle_certified(geo, np.zeros(2), 150.0, 200.0, 10.0)  # above the ceiling
    assert circle_certified(geo, np.zeros(2), 150.0, 140.0, 10.0, margin_v_m=10.0)
    assert not circle_certified(geo, np.zeros(2), 150.0, 141.0, 10.0, margin_v_m=10.0)
    # closed form at the north edge (1000 m): the disc reaches c + R + reserve
    assert circle_certified(geo, np.array([839.0, 0.0]), 150.0, 100.0, 10.0)
    assert not circle_certified(geo, np.array([841.0, 0.0]), 150.0, 100.0, 10.0)
    # the tower (60 m about (-500, 500), a 16-gon, tested face by face: conservative by ~3 m): clears by 8 m / overlaps
    assert circle_certified(geo, np.array([-500.0, 500.0 - 60.0 - 168.0]), 150.0, 100.0, 10.0)
    assert not circle_certified(geo, np.array([-500.0, 500.0 - 60.0 - 157.0]), 150.0, 100.0, 10.0)
