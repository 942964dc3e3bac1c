"""L1 guidance and TECS in isolation: closed-form values and signs."""

import math

import numpy as np
import pytest

from skyherd.flight.fixedwing.guidance import L1Params, circle_capture, l1_distance, loiter, track
from skyherd.flight.fixedwing.tecs import Tecs
from skyherd.flight.geo import GRAVITY

P = L1Params(period=17.0, damping=0.75)
LIMITS = dict(climb_max=2.5, sink_max=3.0, thr_min=0.0, thr_max=1.0, pitch_min=-0.2, pitch_max=0.26)


def test_l1_distance_closed_form():
    assert l1_distance(P, 24.0) == pytest.approx(0.75 * 17.0 * 24.0 / math.pi)


def test_track_on_line_is_quiet_and_offsets_turn_back():
    a, b = np.array([0.0, 0.0]), np.array([1000.0, 0.0])
    v = np.array([24.0, 0.0])
    assert track(P, np.array([100.0, 0.0]), v, a, b).lat_acc == pytest.approx(0.0, abs=1e-12)
    left = track(P, np.array([100.0, -20.0]), v, a, b)  # 20 m left (west) of a northbound line
    right = track(P, np.array([100.0, 20.0]), v, a, b)
    assert left.lat_acc > 0 > right.lat_acc and left.lat_acc == pytest.approx(-right.lat_acc)
    # Park et al.: a = K_L1 V^2 / L1 sin(asin(xt / L1)) = 4 ζ^2 V^2 xt / L1^2 for a parallel course
    l1 = l1_distance(P, 24.0)
    assert left.lat_acc == pytest.approx(4 * 0.75**2 * 24.0**2 * 20.0 / l1**2)
    assert left.xtrack == pytest.approx(-20.0)
    # Heading 30 deg to the right of the line (toward the east): turn left
    v30 = 24.0 * np.array([math.cos(0.5236), math.sin(0.5236)])
    assert track(P, np.array([100.0, 0.0]), v30, a, b).lat_acc < 0


def test_capture_turns_toward_the_target():
    v = np.array([24.0, 0.0])  # northbound
    east = circle_capture(P, np.zeros(2), v, np.array([0.0, 500.0]))
    assert east.lat_acc > 0 and east.nu == pytest.approx(math.pi / 2)
    ahead = circle_capture(P, np.zeros(2), v, np.array([500.0, 0.0]))
    assert ahead.lat_acc == pytest.approx(0.0, abs=1e-12)


@pytest.mark.parametrize("direction", [1, -1])
def test_loiter_on_the_circle_demands_exactly_the_centripetal_acceleration(direction):
    r, v = 130.0, 24.0
    pos = np.array([0.0, -r])  # west of the centre
    vel = np.array([v * direction, 0.0])  # clockwise there = northbound
    d = loiter(P, pos, vel, np.zeros(2), r, direction)
    assert d.lat_acc == pytest.approx(direction * v * v / r)
    assert math.degrees(math.atan(abs(d.lat_acc) / GRAVITY)) == pytest.approx(24.3, abs=0.1)
    # 10 m outside: the PD term adds Kx·10 toward the centre
    out = loiter(P, np.array([0.0, -r - 10.0]), vel, np.zeros(2), r, direction)
    assert direction * out.lat_acc > direction * d.lat_acc


def test_tecs_signs_and_steady_state():
    t = Tecs()
    t.reset(throttle_trim=0.55, pitch_trim=0.03)
    for _ in range(10):
        o = t.update(0.02, 100.0, 0.0, 24.0, 100.0, 24.0, **LIMITS)
    assert o.throttle == pytest.approx(0.55) and o.pitch == pytest.approx(0.03)
    assert o.hdot_dem == 0.0 and o.vdot_dem == 0.0
    low = Tecs()
    low.reset(0.55, 0.03)
    o = low.update(0.02, 90.0, 0.0, 24.0, 100.0, 24.0, **LIMITS)  # 10 m low: climb
    assert o.throttle > 0.55 and o.pitch > 0.03 and o.hdot_dem == pytest.approx(2.5)
    slow = Tecs()
    slow.reset(0.55, 0.03)
    o = slow.update(0.02, 100.0, 0.0, 20.0, 100.0, 24.0, **LIMITS)  # 4 m/s slow: accelerate
    assert o.throttle > 0.55 and o.pitch < 0.03  # more energy, put into speed
    w2 = Tecs()
    w2.reset(0.55, 0.03)
    o = w2.update(0.02, 90.0, 0.0, 24.0, 100.0, 24.0, speed_weight=2.0, **LIMITS)
    assert o.pitch == pytest.approx(0.03)  # speed-only pitch ignores the height error


def test_tecs_never_returns_nan():
    t = Tecs()
    o = t.update(0.02, float("nan"), 0.0, 24.0, 100.0, 24.0, **LIMITS)
    assert math.isfinite(o.throttle) and math.isfinite(o.pitch)
