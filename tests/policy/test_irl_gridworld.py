"""Projection IRL (Abbeel & Ng 2004) on a gridworld with a known linear reward and exact solvers."""

import numpy as np
import pytest

from skyherd.policy.gridworld import GridWorld, region_features
from skyherd.policy.irl import (
    IRLParams,
    mixture_weights,
    projection_irl,
    projection_step,
    select_policy,
)


def _world(gamma=0.9):
    # 6×6 grid; features: two goal cells, a pit, a swamp block, the top-left strip
    F = region_features(6, 6, [[35], [5], [30], [14, 15, 20, 21], [0, 1, 2]])
    return GridWorld(6, 6, F, start=0, gamma=gamma)


@pytest.mark.parametrize(
    "w_true",
    [
        [1.0, 0.6, -0.2, -0.5, 0.1],
        [0.2, 1.0, 0.0, -1.0, 0.0],
        [-0.3, 0.1, 1.0, -0.2, 0.3],
    ],
)
def test_projection_irl_recovers_expert_feature_expectations(w_true):
    g = _world()
    expert = g.value_iteration(np.array(w_true))
    mu_e = g.feature_expectations(expert)
    pi0 = np.zeros(g.n_states, dtype=int)  # "always stay" at the start cell
    eps = 1e-3
    res = projection_irl(
        mu_e, pi0, lambda w, i: g.value_iteration(w), g.feature_expectations, IRLParams(eps, 30)
    )
    assert res.converged and res.t <= eps
    # the margin t never grows (projection onto a growing convex hull)
    ts = [np.linalg.norm(mu_e - res.mu0)] + [h.t for h in res.history]
    assert all(b <= a + 1e-12 for a, b in zip(ts, ts[1:]))
    k = select_policy(res)
    np.testing.assert_allclose(res.mus[k], mu_e, atol=1e-3)
    # the recovered policy earns the expert's value under the TRUE reward
    assert abs(res.mus[k] @ w_true - mu_e @ w_true) < 1e-3
    lam = mixture_weights(res.mus, mu_e)
    assert lam.min() >= 0 and abs(lam.sum() - 1) < 1e-9
    np.testing.assert_allclose(lam @ np.array(res.mus), mu_e, atol=2e-3)


def test_projection_step_is_the_orthogonal_projection():
    rng = np.random.default_rng(3)
    for _ in range(50):
        mb, mi, me = rng.random((3, 4))
        p = projection_step(mb, mi, me)
        # p lies on the line through μ̄ and μ_i, and μ_E − p is orthogonal to that line
        a = mi - mb
        assert abs((me - p) @ a) < 1e-9
        assert np.linalg.matrix_rank(np.stack([p - mb, a]), tol=1e-9) <= 1
    same = projection_step(np.ones(3), np.ones(3), np.zeros(3))
    np.testing.assert_array_equal(same, np.ones(3))


def test_gridworld_feature_expectations_match_closed_form():
    # start on the goal cell of a 1×3 corridor, stay forever: μ = (1 − γ) Σ γ^t ψ(goal) = ψ(goal)
    F = region_features(1, 3, [[0], [2]])
    g = GridWorld(1, 3, F, start=2, gamma=0.8)
    np.testing.assert_allclose(g.feature_expectations(np.zeros(3, int)), [0.0, 1.0])
    # from cell 0 always east: states 0, 1, 2, 2, … → μ_goal = γ²
    g2 = GridWorld(1, 3, F, start=0, gamma=0.8)
    mu = g2.feature_expectations(np.array([3, 3, 0]))
    np.testing.assert_allclose(mu, [1 - 0.8, 0.8**2], atol=1e-12)


def test_irl_rejects_nan_expert():
    g = _world()
    with pytest.raises(ValueError, match="NaN"):
        projection_irl(np.array([np.nan] * 5), np.zeros(36, int), None, g.feature_expectations)
