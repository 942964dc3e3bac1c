"""Quadrotor dynamics against closed forms (flight/quadrotor.py)."""

import dataclasses
import math

import numpy as np
import pytest

from skyherd.flight.frames import quat_to_euler
from skyherd.flight.quadrotor import DEFAULT_AIRFRAME, Quadrotor, QuadrotorParams

P = QuadrotorParams.from_toml()
NO_DRAG = dataclasses.replace(P, drag_linear=(0.0, 0.0, 0.0), drag_quadratic=(0.0, 0.0, 0.0))


def test_airframe_file_matches_defaults_and_checks_units(tmp_path):
    assert P == QuadrotorParams()  # the data file and the dataclass agree
    bad = DEFAULT_AIRFRAME.read_text().replace('unit = "kg" }', 'unit = "g" }')
    (tmp_path / "bad.toml").write_text(bad)
    with pytest.raises(ValueError, match="expected 'kg'"):
        QuadrotorParams.from_toml(tmp_path / "bad.toml")
    (tmp_path / "broken.toml").write_text("[body\nmass = ")
    with pytest.raises(ValueError, match="cannot read"):
        QuadrotorParams.from_toml(tmp_path / "broken.toml")


def test_hover_thrust_equals_weight_at_equilibrium_speed():
    q = Quadrotor(P)
    w_h = math.sqrt(P.mass * P.gravity / (4 * P.k_thrust))  # k_f ω² · 4 = m g
    assert math.isclose(P.hover_command * P.omega_max, w_h)
    q.reset(pos_ned=(0, 0, -20), motor_speed=[w_h] * 4)
    s = q.step(5.0, [P.hover_command] * 4)
    assert math.isclose(q.thrust, P.mass * P.gravity, rel_tol=1e-12)
    assert np.allclose(s.pos_ned, [0, 0, -20], atol=1e-9)
    assert np.allclose(s.vel_ned, 0, atol=1e-9)
    assert np.allclose(s.accel_frd, [0, 0, -P.gravity], atol=1e-9)  # accelerometer reads -g z


def test_free_fall_matches_g_t2_over_2():
    q = Quadrotor(NO_DRAG)
    q.reset(pos_ned=(0, 0, -500))
    for k in range(1, 4):
        s = q.step(1.0, [0, 0, 0, 0])
        t = float(k)
        assert math.isclose(s.pos_ned[2], -500 + 0.5 * P.gravity * t * t, abs_tol=1e-9)
        assert math.isclose(s.vel_ned[2], P.gravity * t, abs_tol=1e-9)
        assert np.allclose(s.accel_frd, 0, atol=1e-12)  # free fall: no specific force


def test_falling_with_drag_reaches_closed_form_terminal_speed():
    # m g = c1 v + c2 v²  (level body, motors off)
    c1, c2 = P.drag_linear[2], P.drag_quadratic[2]
    v_t = (-c1 + math.sqrt(c1 * c1 + 4 * c2 * P.mass * P.gravity)) / (2 * c2)
    q = Quadrotor(P)
    q.reset(pos_ned=(0, 0, -5000))
    s = q.step(30.0, [0, 0, 0, 0])
    assert math.isclose(s.vel_ned[2], v_t, rel_tol=1e-6)


def test_constant_yaw_torque_gives_tau_over_izz():
    q = Quadrotor(NO_DRAG)
    w1, w2 = 700.0, 600.0  # CCW rotors 1, 2 faster: net torque about +z (nose right)
    q.reset(pos_ned=(0, 0, -1000), motor_speed=[w1, w1, w2, w2])
    tau = P.k_torque * (2 * w1**2 - 2 * w2**2)
    alpha = tau / P.inertia[2]
    t = 1.5
    s = q.step(t, np.array([w1, w1, w2, w2]) / P.omega_max)
    assert math.isclose(s.omega_frd[2], alpha * t, rel_tol=1e-9)
    assert np.allclose(s.omega_frd[:2], 0, atol=1e-12)
    roll, pitch, yaw = quat_to_euler(s.quat)
    assert math.isclose(yaw, 0.5 * alpha * t * t, rel_tol=1e-9)
    assert abs(roll) < 1e-12 and abs(pitch) < 1e-12


def test_resting_on_ground_does_not_drift_for_60_s():
    q = Quadrotor(P)
    q.reset(quat=(math.cos(0.3), 0, 0, math.sin(0.3)))
    q0 = q.x[6:10].copy()
    cmd = [0.6, 0.4, 0.5, 0.55]  # below hover, uneven: torques but no lift
    for _ in range(60_000):
        s = q.step(0.001, cmd)
    assert s.on_ground
    assert np.array_equal(s.pos_ned, np.zeros(3))
    assert np.array_equal(s.vel_ned, np.zeros(3))
    assert np.allclose(s.quat, q0, atol=1e-15)
    assert np.allclose(s.accel_frd, [0, 0, -P.gravity])


def test_touchdown_never_sinks_nor_bounces():
    q = Quadrotor(P)
    q.reset(pos_ned=(0, 0, -5), vel_ned=(1.0, 0, 2.0), quat=(0.999, 0.03, 0.02, 0))
    zs, landed_at = [], None
    for k in range(5000):
        s = q.step(0.001, [0.3] * 4)
        zs.append(s.pos_ned[2])
        if s.on_ground and landed_at is None:
            landed_at = k
    assert landed_at is not None and max(zs) <= 0.0
    assert np.all(np.array(zs[landed_at:]) == 0.0)  # stays down: no bounce
    assert np.array_equal(s.vel_ned, np.zeros(3))
    roll, pitch, _ = quat_to_euler(s.quat)
    assert roll == 0.0 and pitch == 0.0
    # full thrust lifts it off again
    s = q.step(0.5, [1, 1, 1, 1])
    assert not s.on_ground and s.pos_ned[2] < -0.1


def test_bad_commands_never_propagate():
    q = Quadrotor(P)
    q.reset(pos_ned=(0, 0, -10))
    s = q.step(0.1, [np.nan, np.inf, -np.inf, -3.0])
    assert all(np.all(np.isfinite(a)) for a in (s.pos_ned, s.vel_ned, s.quat, s.omega_frd))
    assert q.motor_speed[0] == 0.0 and q.motor_speed[2] == 0.0 and q.motor_speed[1] > 0
    with pytest.raises(ValueError):
        q.step(float("nan"), [0, 0, 0, 0])


def test_integration_is_deterministic_and_substeps_equal_single_steps():
    rng = np.random.default_rng(0)
    cmds = rng.uniform(0.6, 0.8, size=(500, 4))
    a, b = Quadrotor(P), Quadrotor(P)
    for q in (a, b):
        q.reset(pos_ned=(0, 0, -50))
    for c in cmds:
        a.step(0.004, c)
        for _ in range(4):
            b.step(0.001, c)
    assert a.x.tobytes() == b.x.tobytes()
    assert a.time_us == b.time_us == 2_000_000


def test_wind_drag_closed_form_and_drift_to_wind_speed():
    q = Quadrotor(P)
    w_h = P.hover_command * P.omega_max
    q.reset(pos_ned=(0, 0, -100), motor_speed=[w_h] * 4)
    q.wind_ned = (5.0, 0.0, 0.0)
    s = q.step(0.001, [P.hover_command] * 4)
    f = P.drag_linear[0] * 5.0 + P.drag_quadratic[0] * 25.0  # air-relative speed 5 m/s
    assert s.accel_frd[0] == pytest.approx(f / P.mass, rel=1e-3)
    s = q.step(200.0, [P.hover_command] * 4)  # linear-drag time constant m/c₁ = 15 s
    assert s.vel_ned[0] == pytest.approx(5.0, abs=1e-3)  # carried along with the air
    assert abs(s.vel_ned[2]) < 1e-9
    with pytest.raises(ValueError):
        q.wind_ned = (np.nan, 0, 0)


def test_gust_process_statistics_and_seed():
    from skyherd.flight.quadrotor import WindField, WindModel

    m = WindModel(mean_ned=(2.0, 0.0, 0.0), gust_std=1.5, gust_tau=2.0, seed=7)
    a = np.array([WindField(m).sample(0.01) for _ in range(1)])
    f1, f2 = WindField(m), WindField(m)
    x1 = np.array([f1.sample(0.01) for _ in range(100_000)])
    x2 = np.array([f2.sample(0.01) for _ in range(100_000)])
    assert x1.tobytes() == x2.tobytes() and a.shape == (1, 3)
    assert x1[:, 0].mean() == pytest.approx(2.0, abs=0.3)
    assert x1[:, 1].std() == pytest.approx(1.5, rel=0.2)  # stationary std σ
    lag = round(2.0 / 0.01)  # correlation at τ is e⁻¹
    g = x1[:, 2] - x1[:, 2].mean()
    rho = np.dot(g[:-lag], g[lag:]) / np.dot(g, g)
    assert rho == pytest.approx(math.exp(-1.0), abs=0.15)
    with pytest.raises(ValueError):
        WindModel(gust_std=-1.0)
