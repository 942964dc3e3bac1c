"""JSBSim J3Cub wrapper: quiet loading, frames, trimmed flight, bad input."""

import math

import numpy as np
import pytest

from skyherd.flight.fixedwing.jsbsim_model import JSBSimPlane, ModelParams, Surfaces
from skyherd.flight.frames import quat_to_dcm
from skyherd.flight.geo import GRAVITY, Home


@pytest.fixture(scope="module")
def plane():
    return JSBSimPlane()


def test_loads_quietly(capfd):
    JSBSimPlane()
    out, err = capfd.readouterr()
    assert out == "" and err == ""


def test_resting_on_gear(plane):
    plane.reset_on_ground(heading=0.0)
    s = plane.state()
    assert s.on_ground
    roll, pitch, yaw = s.euler
    # Taildragger three-point attitude: nose up about 12 deg, wings level, heading kept.
    assert 0.15 < pitch < 0.25 and abs(roll) < 0.02 and abs(yaw) < 0.01
    # An accelerometer at rest reads -g along world down, expressed in the body frame.
    f_world = quat_to_dcm(s.quat) @ s.accel_frd
    assert np.allclose(f_world, [0, 0, -GRAVITY], atol=0.35)
    assert np.linalg.norm(s.vel_ned) < 0.05
    assert 0.8 < plane.ground_cg_height < 1.5 and abs(s.altitude - plane.ground_cg_height) < 0.1
    assert plane.get_property("propulsion/engine/set-running") == 0.0  # engine off until armed


def test_trimmed_level_flight_holds_60s(plane):
    """Issue 7: trimmed level flight holds altitude +-2 m and airspeed +-1 m/s for 60 s."""
    trim = plane.reset_airborne(altitude=100.0, airspeed=20.0, heading=0.0)
    assert 0.2 < trim.throttle < 0.9
    h, v = [], []
    for _ in range(3000):
        s = plane.step(0.02, trim)
        h.append(s.altitude)
        v.append(plane.airspeed)
    assert max(abs(x - 100.0) for x in h) < 2.0
    assert max(abs(x - 20.0) for x in v) < 1.0


def test_frames_heading_east_and_position_integrates_velocity(plane):
    trim = plane.reset_airborne(altitude=80.0, airspeed=22.0, heading=math.pi / 2)
    s0 = plane.state()
    assert abs(s0.euler[2] - math.pi / 2) < 1e-3
    # Body forward points east in NED.
    fwd = quat_to_dcm(s0.quat) @ [1.0, 0.0, 0.0]
    assert fwd[1] > 0.99
    assert s0.vel_ned[1] > 21.0 and abs(s0.vel_ned[0]) < 0.5
    integ = np.zeros(3)
    prev = s0
    for _ in range(500):  # 10 s
        s = plane.step(0.02, trim)
        integ += 0.5 * (prev.vel_ned + s.vel_ned) * 0.02
        prev = s
    # Geodetic → NED (flight.geo) agrees with the integrated NED velocity to 0.5 %.
    assert np.allclose(s.pos_ned - s0.pos_ned, integ, atol=0.005 * np.linalg.norm(integ))
    assert abs(s.t - s0.t - 10.0) < 1e-9


def test_home_elsewhere_keeps_ned_about_home():
    home = Home(47.0, 8.0, 400.0)
    p = JSBSimPlane(home=home)
    s = p.state()
    assert np.linalg.norm(s.pos_ned[:2]) < 0.5 and abs(s.altitude - p.ground_cg_height) < 0.1


def test_control_signs(plane):
    """Our convention: + aileron rolls right, + elevator noses up, + rudder yaws right."""
    for field, axis, sign in (("aileron", 0, 1), ("elevator", 1, 1), ("rudder", 2, 1)):
        trim = plane.reset_airborne(altitude=100.0, airspeed=24.0)
        cmd = Surfaces(**{**trim.__dict__, field: getattr(trim, field) + 0.3 * sign})
        for _ in range(15):
            s = plane.step(0.02, cmd)
        assert s.omega_frd[axis] * sign > 0.03, field


def test_bad_input(plane):
    assert Surfaces(float("nan"), 2.0, -3.0, float("inf"), -1).clipped() == Surfaces(0, 1, -1, 0, 0)
    plane.reset_airborne(altitude=100.0, airspeed=22.0)
    s = plane.step(0.02, Surfaces(aileron=float("nan"), throttle=float("nan")))
    assert np.all(np.isfinite(s.pos_ned))
    with pytest.raises(ValueError):
        plane.step(0.0123, Surfaces())
    with pytest.raises(ValueError):
        plane.set_wind(np.array([np.nan, 0, 0]))
    with pytest.raises(ValueError):
        JSBSimPlane(params=ModelParams(aircraft="../../etc"))
    with pytest.raises(ValueError):
        JSBSimPlane(params=ModelParams(physics_dt=0.5))
