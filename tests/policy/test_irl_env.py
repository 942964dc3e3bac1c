"""skyherd/GroundAir-v0: registration, env checker, fast φ against perception, UAV model, episodes."""

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from skyherd import policy
from skyherd.perception.camera import CameraParams, camera_pose
from skyherd.perception.features import features_from_truth
from skyherd.policy.demos import random_policy, rollout_stats, scripted_expert
from skyherd.policy.groundair.env import GroundAirEnv, reward_features
from skyherd.task.fastphi import LevelCamera, min_circle
from skyherd.task.observation import OBS_DIM
from skyherd.task.params import TaskParams


def test_registered_on_import_and_passes_env_checker():
    env = gym.make(policy.ENV_ID)
    check_env(env.unwrapped, skip_render_check=False)
    for sc in ("lateral", "climb", "descend"):
        check_env(gym.make(policy.ENV_ID, scenario=sc).unwrapped)
    o, _ = env.reset(seed=0)
    assert o.shape == (OBS_DIM,) and o.dtype == np.float32
    with pytest.raises(ValueError):
        GroundAirEnv("nope")
    with pytest.raises(ValueError):
        GroundAirEnv(reward_weights=[np.nan] * 9)


def test_policy_import_is_light():
    import subprocess
    import sys

    code = "import sys, skyherd.policy; print([m in sys.modules for m in ('torch', 'gymnasium')])"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[False, False]"


def test_gym_make_with_the_module_prefix_in_a_fresh_interpreter():
    """gymnasium's `module:id` form: the task registers itself on that import."""
    import subprocess
    import sys

    code = (
        "import gymnasium as gym; env = gym.make('skyherd.policy:skyherd/GroundAir-v0', "
        "scenario='lateral'); print(env.observation_space.shape)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "(14,)"


def test_gymnasium_entry_point_module_colon_env_id_in_a_fresh_interpreter():
    """gymnasium 1.4's "module:env_id": `gym.make` imports skyherd.policy, whose import
    registers the env; nothing of skyherd imported before (a new interpreter)."""
    import os
    import subprocess
    import sys

    code = ("import sys, gymnasium as gym\n"
            "assert 'skyherd' not in sys.modules\n"
            "env = gym.make('skyherd.policy:skyherd/GroundAir-v0', scenario='climb')\n"
            "o, _ = env.reset(seed=0)\n"
            "print(type(env.unwrapped).__name__, o.shape, env.unwrapped.scenario)")  # fmt: skip
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["GroundAirEnv", "(14,)", "climb"]


def test_fast_phi_equals_perception_features():
    cam = CameraParams()
    lc = LevelCamera(cam)
    rng = np.random.default_rng(0)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    checked_partial = 0
    for _ in range(300):
        n, e, alt = rng.uniform(-10, 10), rng.uniform(-10, 10), rng.uniform(6, 55)
        ugvs = [(rng.uniform(-25, 25), rng.uniform(-25, 25)) for _ in range(3)]
        fast, seen, _ = lc.phi(n, e, alt, ugvs)
        pose = camera_pose(cam, np.array([n, e, -alt]), q)
        pts = np.array([[a, b, 0.0] for a, b in ugvs])
        ref = features_from_truth(cam, pose, pts, alt)
        # cv2.minEnclosingCircle works in float32: spread agrees to ~1e-5
        np.testing.assert_allclose(fast, ref, atol=2e-5)
        checked_partial += 0 < sum(seen) < 3
    assert checked_partial > 20  # partial views were exercised too


def test_min_circle_closed_forms():
    assert min_circle([(0.0, 0.0), (4.0, 0.0)]) == (2.0, 0.0, 2.0)
    # obtuse triangle: the circle on the longest side
    cu, cv, r = min_circle([(0.0, 0.0), (10.0, 0.0), (5.0, 1.0)])
    assert (cu, cv, r) == pytest.approx((5.0, 0.0, 5.0))
    # equilateral triangle of side s: circumradius s/√3
    cu, cv, r = min_circle([(0.0, 0.0), (2.0, 0.0), (1.0, math.sqrt(3))])
    assert r == pytest.approx(2 / math.sqrt(3))


def test_uav_first_order_response_is_exact():
    env = GroundAirEnv("climb", start_noise=False)
    env.reset(seed=1)
    n0, alt0 = env.n, env.alt
    u, dt = env.task.uav, env.task.dt_s
    k = math.exp(-dt / u.tau_s)
    env.step(1)  # north from rest
    assert env.vn == pytest.approx(u.v_xy_mps * (1 - k), rel=1e-12)
    assert env.n - n0 == pytest.approx(u.v_xy_mps * (dt - u.tau_s * (1 - k)), rel=1e-12)
    for _ in range(20):
        env.step(1)
    assert env.vn == pytest.approx(u.v_xy_mps, rel=1e-6)  # settles at the command
    env.step(5)  # climb: altitude rises, down-velocity negative
    assert env.alt > alt0 and env.vd < 0
    assert abs(env.vd) <= u.v_up_mps


def test_altitude_geofence_and_lost_termination():
    env = GroundAirEnv("composite", start_noise=False)
    env.reset(seed=0)
    for _ in range(200):
        _, _, term, trunc, _ = env.step(6)
        assert env.alt >= env.task.uav.alt_min_m
        if term or trunc:
            break
    # flying off north loses everyone: termination after lost_s of empty frames
    env.reset(seed=0)
    steps = 0
    while True:
        _, _, term, trunc, info = env.step(1)
        steps += 1
        if term or trunc:
            break
    assert term and not trunc and steps < env.task.max_steps
    m = info["metrics"]
    assert m["all_in_view_frac"] < 0.5 and m["ugv_losses"] >= 3


def test_episode_truncates_at_time_limit_and_metrics():
    from skyherd.perception.features import spread_circle

    env = GroundAirEnv("descend", task=TaskParams(episode_s=10.0), start_noise=False)
    env.reset(seed=0)
    cam = env.task.camera
    ratios = []
    for i in range(20):
        _, _, term, trunc, info = env.step(0)
        assert trunc == (i == 19) and not term
        z = env.alt - cam.mount_offset_frd[2]
        area = (cam.width_px * z / cam.fx) * (cam.height_px * z / cam.fx)
        _, r = spread_circle(np.array(env.formation.positions()))
        ratios.append(area / (math.pi * r * r))
    m = info["metrics"]
    assert m["all_in_view_frac"] == 1.0 and m["ugv_losses"] == 0
    assert m["footprint_ratio"] == pytest.approx(np.mean(ratios), rel=1e-4)
    # the team shrinks while the UAV hovers: the ratio grows step by step
    assert ratios[-1] > ratios[0]


def test_reward_features():
    psi = reward_features([0.5, 0.25, 0.35, 0.5, 1.0, 1.0, 0.4, 1.0])
    assert psi == pytest.approx([1.0, 1.0, 0.5, 0.4, 0, 0, 1, 0, 0])
    psi = reward_features([0.5, 0.5, 0.0, 0.3, 0.0, 0.0, 0.0, 1.0])  # nothing in view
    assert psi == [0.0] * 9


@pytest.mark.parametrize("scenario", ["lateral", "climb", "descend", "composite"])
def test_scripted_expert_beats_random(scenario):
    _, me = rollout_stats(scripted_expert(scenario), scenario, 10, 500, 0.97)
    _, mr = rollout_stats(random_policy(0), scenario, 10, 500, 0.97)
    assert me["all_in_view_frac"] >= 0.9
    # random either loses the team or (descend) leaves the view far too wide
    assert me["all_in_view_frac"] > mr["all_in_view_frac"] + 0.3 or (
        me["footprint_ratio"] < 0.6 * mr["footprint_ratio"]
    )


def test_groundsim_behaviours_drive_the_ugvs():
    from skyherd.policy.demos import ALLOWED_ACTIONS, ExpertParams, ScriptedExpert
    from skyherd.task.scenarios import GROUNDSIM_SCENARIOS

    check_env(gym.make(policy.ENV_ID, scenario="groundsim:route").unwrapped)
    res = {}
    for sc in ("groundsim:route", "groundsim:camouflage"):
        ex = ScriptedExpert(ALLOWED_ACTIONS["composite"], ExpertParams(), np.random.default_rng(0))
        _, res[sc] = rollout_stats(ex, sc, 2, 7, 0.97)
    assert res["groundsim:route"]["all_in_view_frac"] > 0.9
    # one UGV is camouflaged for 15 s of the 60 s: the expert cannot see all three then
    assert res["groundsim:camouflage"]["all_in_view_frac"] < 0.8
    assert len(GROUNDSIM_SCENARIOS) == 6


def test_transfer_table_on_a_run_folder(tmp_path, capsys):
    from skyherd.policy.dqn import MLPPolicy
    from skyherd.policy.evaluate import write_transfer
    from skyherd.scripts.cli import main

    with pytest.raises(ValueError, match="no policies/ folder"):
        write_transfer(tmp_path)
    assert main(["transfer", str(tmp_path)]) == 2
    (tmp_path / "policies").mkdir()
    rng = np.random.default_rng(0)
    pol = MLPPolicy(
        [rng.normal(size=(8, 14)), rng.normal(size=(7, 8))],
        [np.zeros(8), np.zeros(7)],
        {"learner": "irl", "eval": {"all_in_view_frac": 0.5}},
    )
    pol.save(tmp_path / "policies" / "irl_seed0.npz")
    assert main(["transfer", str(tmp_path), "--episodes", "1"]) == 0
    text = (tmp_path / "transfer.md").read_text()
    assert "irl (irl_seed0)" in text and "groundsim:speedoff" in text and "expert (ideal)" in text


def test_pixel_observations_agree_with_the_fast_path():
    """pixels=True: perception's OpenCV renderer + detector give nearly the fast path's φ."""
    check_env(gym.make(policy.ENV_ID, pixels=True).unwrapped)
    a, b = GroundAirEnv("composite"), GroundAirEnv("composite", pixels=True)
    oa, _ = a.reset(seed=3)
    ob, _ = b.reset(seed=3)
    ex = scripted_expert("composite")
    diffs = []
    for _ in range(60):
        act = ex(oa)
        oa, *_ = a.step(act)
        ob, *_ = b.step(act)
        diffs.append(np.abs(oa - ob))
    d = np.array(diffs)
    assert b.last_frame.shape == (240, 320, 3)
    # centroid within 0.01 of the image, spread within 0.015 (markers sit 0.42 m above ground)
    assert d[:, :2].max() < 0.01 and d[:, 2].max() < 0.015
    np.testing.assert_array_equal(d[:, 3:6], 0.0)  # altitude, fractions: identical


def test_kept_policy_flies_through_pixels():
    from skyherd.policy.models import DEFAULT_POLICY

    pol = policy.load_policy(DEFAULT_POLICY)
    _, m = rollout_stats(pol, "composite", 6, 300_000, 0.97, pixels=True)
    assert m["all_in_view_frac"] >= 0.9


def test_uav_commands_inside_the_autopilot_limits():
    from skyherd.task.params import UAVParams, autopilot_velocity_limits

    lim = autopilot_velocity_limits()
    assert lim == {"xy": 12.0, "up": 3.0, "down": 1.5}
    with pytest.raises(ValueError, match="autopilot"):
        UAVParams(v_down_mps=lim["down"] + 0.5)
    with pytest.raises(ValueError):
        UAVParams(alt_min_m=70.0)


def test_vertical_time_constant_and_sitl_dynamics():
    from skyherd.policy.models import DEFAULT_POLICY
    from skyherd.task.params import SITL_MEASURED, UAVParams

    u = UAVParams(tau_s=0.5, tau_z_s=0.25)
    env = GroundAirEnv("climb", task=TaskParams(uav=u), start_noise=False)
    env.reset(seed=0)
    env.step(5)
    kz = math.exp(-0.5 / 0.25)
    assert env.vd == pytest.approx(-u.v_up_mps * (1 - kz), rel=1e-12)
    # the kept policy, trained with τ = 0.6 s, on the SITL quadrotor's measured response
    pol = policy.load_policy(DEFAULT_POLICY)
    _, m = rollout_stats(pol, "composite", 10, 300_000, 0.97, task=TaskParams(uav=SITL_MEASURED))
    assert m["all_in_view_frac"] >= 0.9


def test_attitude_mode_tilts_the_camera_with_the_acceleration():
    from skyherd.flight.frames import quat_to_euler

    lvl, tlt = (
        GroundAirEnv("lateral", start_noise=False),
        GroundAirEnv("lateral", attitude=True, start_noise=False),
    )
    o1, _ = lvl.reset(seed=2)
    o2, _ = tlt.reset(seed=2)
    np.testing.assert_allclose(o1, o2, atol=1e-5)  # at rest: level, the same view
    tlt.step(1)  # accelerate north from rest
    u, dt = tlt.task.uav, tlt.task.dt_s
    a = u.v_xy_mps * math.exp(-dt / u.tau_s) / u.tau_s  # (v_cmd − v)/τ at the end of the step
    roll, pitch, yaw = quat_to_euler(tlt.quat())
    assert pitch == pytest.approx(-math.atan(a / 9.80665), abs=1e-9)
    assert roll == pytest.approx(0.0, abs=1e-12) and yaw == pytest.approx(0.0, abs=1e-12)
    # nose down: the body-fixed camera looks behind (south of) the UAV, so the team moves up
    # the image (com_v falls) relative to the level camera after the same step
    lvl.step(1)
    assert tlt._phi_prev[1] < lvl._phi_prev[1] - 0.05
