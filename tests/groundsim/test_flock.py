"""skyherd.groundsim.flock against closed forms: eqs. (1)–(5) of docs/shepherding.md."""

import math

import numpy as np
import pytest

from skyherd.groundsim.flock import Flock, FlockParams, flock_spread, new_headings

QUIET = dict(e=0.0, graze_p=0.0)  # no noise, no grazing: the closed forms hold exactly


def flock_of(pos, **kw) -> Flock:
    p = FlockParams(n=len(pos), **{**QUIET, **kw})
    return Flock(np.array(pos, dtype=float), p, np.random.default_rng(0))


def test_a_lone_agent_at_rest_runs_straight_away_from_the_shepherd():
    """(1), (4), (5): no neighbours, no inertia → Ĥ' = R̂^s; after T it is v·T further away."""
    f = flock_of([[3.0, 4.0]])
    f.set_shepherd([0.0, 0.0])
    f.step(0.0, 1.3)
    v = f.p.speed_mps
    np.testing.assert_allclose(f.pos[0], np.array([3.0, 4.0]) * (1 + v * 1.3 / 5.0), atol=1e-12)


def test_inertia_bends_the_escape_by_atan(h=0.5):
    """(4): at rest heading east then the shepherd due south: H' = h·east + ρ_s·north, so the
    agent leaves at atan2(h, ρ_s) east of north."""
    f = flock_of([[10.0, 0.0]], h=h)
    f.heading[0] = [0.0, 1.0]
    f.set_shepherd([0.0, 0.0])
    f.step(0.0, 0.5)
    d = f.pos[0] - [10.0, 0.0]
    assert math.atan2(d[1], d[0]) == pytest.approx(math.atan2(h, 1.0), abs=1e-12)
    assert np.linalg.norm(d) == pytest.approx(f.p.speed_mps * 0.5, abs=1e-12)


def test_beyond_the_sensing_radius_nothing_moves():
    f = flock_of([[40.0, 0.0], [40.0, 10.0]])
    f.set_shepherd([0.0, 0.0])  # 40 m > r_s = 30 m
    f.step(0.0, 5.0)
    np.testing.assert_array_equal(f.pos, [[40.0, 0.0], [40.0, 10.0]])


def test_two_close_agents_push_apart_along_their_line():
    """(2): closer than r_a and undisturbed, each moves directly away from the other."""
    f = flock_of([[0.0, 0.0], [0.0, 1.0]])
    f.step(0.0, 0.5)
    np.testing.assert_allclose(f.pos, [[0.0, -0.75], [0.0, 1.75]], atol=1e-12)


def test_cohesion_pulls_a_pair_together_in_closed_form():
    """(3), (4): two agents 10 m apart across the shepherd's axis, 20 m ahead of it, h = 0:
    H' = c·Ĉ + ρ_s·R̂^s; each moves v·dt along its normalised H' and the gap shrinks by that."""
    f = flock_of([[20.0, -5.0], [20.0, 5.0]], h=0.0)
    f.set_shepherd([0.0, 0.0])
    f.step(0.0, 0.5)
    c, rho = f.p.c, f.p.rho_s
    r = np.array([20.0, 5.0]) / math.hypot(20.0, 5.0)
    h = c * np.array([0.0, -1.0]) + rho * r  # agent at east +5
    step = f.p.speed_mps * 0.5 * h / np.linalg.norm(h)
    np.testing.assert_allclose(f.pos[1], [20.0 + step[0], 5.0 + step[1]], atol=1e-12)
    np.testing.assert_allclose(f.pos[0], [20.0 + step[0], -5.0 - step[1]], atol=1e-12)
    assert f.pos[1, 1] - f.pos[0, 1] < 10.0


def test_a_pressed_flock_gathers_and_without_attraction_it_does_not():
    spreads = {}
    for c in (1.05, 0.0):
        p = FlockParams(c=c, start_half_m=12.0)
        f = Flock.start(p, np.random.default_rng(3))
        s0 = flock_spread(f.pos)
        for k in range(200):  # 20 s with the shepherd 25 m south of the centre
            f.set_shepherd(f.pos.mean(axis=0) - [25.0, 0.0])
            f.step(0.1 * k, 0.1)
        spreads[c] = flock_spread(f.pos) / s0
    assert spreads[1.05] < 0.6 < spreads[0.0]


def test_headings_are_seeded():
    pos = np.random.default_rng(1).uniform(-5, 5, (10, 2))
    a = new_headings(pos, np.zeros((10, 2)), [0.0, 0.0], FlockParams(), np.random.default_rng(7))
    b = new_headings(pos, np.zeros((10, 2)), [0.0, 0.0], FlockParams(), np.random.default_rng(7))
    np.testing.assert_array_equal(a[0], b[0])
