"""UGV behaviours and the kinematic unicycle world: closed-form and scripted checks."""

import math

import numpy as np
import pytest

from skyherd.groundsim.behaviours import (
    Camouflage,
    Convoy,
    DriveParams,
    RandomWalk,
    SpeedOff,
    StopAndGo,
    UGVCommand,
    WaypointRoute,
    make_behaviour,
    triangle_offsets,
    wheel_speeds,
)
from skyherd.groundsim.kinematic import KinematicWorld, unicycle_step
from skyherd.groundsim.ugv import UGVModel, UGVStates, initial_states, marker_corners_ned

P = DriveParams()


def run(world, seconds, dt=0.05, t0=0.0):
    t = t0
    for _ in range(int(round(seconds / dt))):
        world.step(t, dt)
        t += dt
    return t


def test_unicycle_exact_arc_and_straight_line():
    s = UGVStates(np.zeros((2, 2)), np.array([0.0, math.pi / 2]), np.array([2.0, 2.0]))
    cmd = UGVCommand(np.array([2.0, 2.0]), np.array([0.5, 0.0]), np.zeros(2, bool))
    for _ in range(100):  # 10 s
        s = unicycle_step(s, cmd, 0.1, P)
    # UGV 0: circle of radius v/ω = 4 m turning right (clockwise) from heading north
    psi = 0.5 * 10.0
    assert s.pos_ne[0] == pytest.approx([4 * math.sin(psi), 4 * (1 - math.cos(psi))], abs=1e-9)
    # UGV 1: straight east 20 m
    assert s.pos_ne[1] == pytest.approx([0.0, 20.0], abs=1e-9)


def test_speed_slews_at_accel_limit():
    s = initial_states(np.zeros((1, 2)))
    cmd = UGVCommand(np.array([5.0]), np.zeros(1), np.zeros(1, bool))
    s = unicycle_step(s, cmd, 1.0, P)
    assert s.speed[0] == pytest.approx(P.accel_max * 1.0)


def test_wheel_speeds_turn_right_means_left_faster():
    left, right = wheel_speeds(np.array([1.0]), np.array([0.5]), 0.6)
    assert left[0] == pytest.approx(1.15) and right[0] == pytest.approx(0.85)


def test_route_formation_reaches_each_corner_and_stops():
    route = np.array([[0.0, 0.0], [30.0, 0.0], [30.0, 30.0]])
    off = triangle_offsets(3)
    b = WaypointRoute(route, off, P)
    w = KinematicWorld(initial_states(off), b, P)
    run(w, 60.0)
    assert b.done().all()
    assert np.hypot(*(w.states.pos_ne - (route[-1] + off)).T).max() < P.arrive_m
    assert np.all(w.states.speed < 0.2)


def test_convoy_keeps_spacing():
    route = np.array([[0.0, 0.0], [200.0, 0.0]])
    w = KinematicWorld(
        initial_states(np.array([[0.0, 0.0], [-10.0, 0.0], [-20.0, 0.0]])),
        Convoy(route, spacing_m=5.0, params=P, loop=False),
        P,
    )
    run(w, 40.0)
    gaps = np.hypot(*np.diff(w.states.pos_ne, axis=0).T)
    # leader at cruise speed; followers close the gap to spacing + v/k_gap
    assert w.states.speed[0] == pytest.approx(P.v_cruise, abs=1e-6)
    assert gaps == pytest.approx(5.0 + P.v_cruise / 1.0, abs=0.2)


def test_random_walk_stays_in_area_and_is_seeded():
    area = (-10.0, 10.0, -5.0, 5.0)

    def trace(seed):
        w = KinematicWorld(
            initial_states(np.zeros((3, 2))),
            RandomWalk(area, 3, np.random.default_rng(seed), P),
            P,
        )
        out = []
        t = 0.0
        for _ in range(1200):
            w.step(t, 0.1)
            t += 0.1
            out.append(w.states.pos_ne.copy())
        return np.array(out)

    a, b, c = trace(7), trace(7), trace(8)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    # the turning circle (v/ω_max ≈ 1.7 m) is the only excursion outside the area
    assert a[..., 0].min() > -12 and a[..., 0].max() < 12
    assert a[..., 1].min() > -7 and a[..., 1].max() < 7
    assert np.ptp(a[..., 0]) > 10  # it does wander


def test_stop_and_go_timeline():
    b = StopAndGo(make_behaviour("route", 3, np.random.default_rng(0)), go_s=5.0, stop_s=3.0)
    w = KinematicWorld(initial_states(triangle_offsets(3)), b, P)
    t = run(w, 4.9)
    assert np.all(w.states.speed > 1.9)
    t = run(w, 1.5, t0=t)  # stopping: slews down at accel_max (2 m/s^2) within 1 s
    assert np.all(w.states.speed == 0.0)
    p = w.states.pos_ne.copy()
    t = run(w, 1.4, t0=t)  # still in the stop phase (5..8 s)
    assert np.array_equal(w.states.pos_ne, p)
    run(w, 2.0, t0=t)
    assert np.all(w.states.speed > 0.5)


def test_speed_off_escapes_the_group():
    b = SpeedOff(make_behaviour("route", 3, np.random.default_rng(0)), 2, 5.0, 6.0, params=P)
    w = KinematicWorld(initial_states(triangle_offsets(3)), b, P)
    run(w, 5.0)
    p0, h0 = w.states.pos_ne[2].copy(), w.states.heading[2]
    d0 = np.hypot(*(w.states.pos_ne[2] - w.states.pos_ne[:2].mean(0)))
    run(w, 10.0, t0=5.0)
    d1 = np.hypot(*(w.states.pos_ne[2] - w.states.pos_ne[:2].mean(0)))
    assert w.states.speed[2] == pytest.approx(6.0, abs=1e-6)
    assert w.states.heading[2] == pytest.approx(h0)  # straight on
    # 2 → 6 m/s at 2 m/s^2 (2 s, 8 m), then 8 s at 6 m/s: 56 m
    assert np.hypot(*(w.states.pos_ne[2] - p0)) == pytest.approx(56.0, abs=0.2)
    assert d1 > d0 + 25.0  # the others keep cruising at 2 m/s


def test_camouflage_flag_window():
    b = Camouflage(make_behaviour("route", 3, np.random.default_rng(0)), 1, 2.0, 4.0)
    s = initial_states(triangle_offsets(3))
    flags = [b.command(t, s).camouflaged.tolist() for t in (1.9, 2.0, 3.9, 4.0)]
    assert flags == [[False] * 3, [False, True, False], [False, True, False], [False] * 3]


def test_make_behaviour_names_and_bad_name():
    for name in ("route", "convoy", "random", "stopgo", "speedoff", "camouflage"):
        make_behaviour(name, 3, np.random.default_rng(0))
    with pytest.raises(ValueError, match="unknown behaviour"):
        make_behaviour("teleport", 3, np.random.default_rng(0))


def test_marker_corners_square_around_centre():
    s = UGVStates(np.array([[5.0, -2.0]]), np.array([0.3]), np.zeros(1))
    c = marker_corners_ned(s, UGVModel())[0]
    assert np.allclose(c[:, :2].mean(0), [5.0, -2.0])
    sides = np.hypot(*np.diff(np.vstack([c, c[:1]])[:, :2], axis=0).T)
    assert np.allclose(sides, 1.0)


def test_kinematic_world_rejects_bad_dt():
    w = KinematicWorld(initial_states(np.zeros((1, 2))), make_behaviour("route", 1, None), P)
    for dt in (0.0, -1.0, math.nan):
        with pytest.raises(ValueError):
            w.step(0.0, dt)
