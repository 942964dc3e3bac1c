"""DQN: solves a tiny task with a fixed seed; checkpoints and policy files."""

import numpy as np
import pytest

from skyherd.policy.dqn import (
    DQNParams,
    MLPPolicy,
    PolicyFileError,
    ReplayBuffer,
    epsilon_at,
    load_policy,
    train_dqn,
)
from skyherd.policy.gridworld import GridGoalEnv

TINY = DQNParams(
    total_steps=3000,
    learning_starts=300,
    target_update_every=200,
    eps_fraction=0.5,
    hidden=(32, 32),
    train_every=1,
    seed=0,
)


def _greedy_rollout(env, policy):
    o, _ = env.reset()
    n, ret, done = 0, 0.0, False
    while not done:
        o, r, te, tr, _ = env.step(policy(o))
        n, ret, done = n + 1, ret + r, te or tr
    return n, ret, te


@pytest.mark.parametrize("double", [True, False])
@pytest.mark.slow
def test_dqn_solves_grid_goal_with_fixed_seed(tmp_path, double):
    import dataclasses

    env = GridGoalEnv(size=5)
    p = dataclasses.replace(TINY, double=double)
    res = train_dqn(env, p, checkpoint=tmp_path / "ck.pt", checkpoint_every=1000)
    n, ret, reached = _greedy_rollout(env, res.policy)
    assert reached and n == 8  # the shortest path: 4 south + 4 east
    assert ret == pytest.approx(1.0 - 0.05 * 7)
    assert res.updates == p.total_steps - p.learning_starts
    # checkpoint is a complete torch file with the hyper-parameters
    import torch

    ck = torch.load(tmp_path / "ck.pt", weights_only=False)
    assert ck["step"] == p.total_steps and ck["params"]["double"] is double
    assert not list(tmp_path.glob(".*tmp*"))  # no temp files left behind


def test_dqn_is_reproducible():
    env = GridGoalEnv(size=4)
    p = DQNParams(total_steps=600, learning_starts=100, hidden=(16,), seed=5)
    a = train_dqn(env, p)
    b = train_dqn(GridGoalEnv(size=4), p)
    for wa, wb in zip(a.policy.weights, b.policy.weights):
        np.testing.assert_array_equal(wa, wb)


def test_policy_file_roundtrip_and_bad_files(tmp_path):
    rng = np.random.default_rng(0)
    pol = MLPPolicy(
        [rng.normal(size=(8, 3)), rng.normal(size=(4, 8))], [np.zeros(8), np.ones(4)], {"x": 1}
    )
    pol.save(tmp_path / "p.npz")
    back = load_policy(tmp_path / "p.npz")
    obs = rng.random((20, 3))
    np.testing.assert_allclose(back.q_values(obs), pol.q_values(obs), rtol=1e-5, atol=1e-5)
    assert [back(o) for o in obs] == [pol(o) for o in obs]
    assert back.meta["x"] == 1 and back.n_actions == 4
    with pytest.raises(ValueError):
        back(np.array([np.nan, 0.0, 0.0]))
    raw = (tmp_path / "p.npz").read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 2])
    with pytest.raises(PolicyFileError, match="not a readable"):
        load_policy(tmp_path / "cut.npz")
    with pytest.raises(PolicyFileError, match="no such"):
        load_policy(tmp_path / "missing.npz")
    np.savez(tmp_path / "foreign.npz", meta=np.array('{"format": "other"}'))
    with pytest.raises(PolicyFileError, match="unknown policy format"):
        load_policy(tmp_path / "foreign.npz")


def test_replay_buffer_and_schedule():
    buf = ReplayBuffer(4, 2)
    for i in range(6):
        buf.add(np.full(2, i), i, float(i), np.full(2, i + 1), i == 5)
    assert len(buf) == 4 and set(buf.act) == {2, 3, 4, 5}
    o, a, r, o2, d = buf.sample(np.random.default_rng(0), 32)
    np.testing.assert_array_equal(o[:, 0], a)
    np.testing.assert_array_equal(d, (a == 5).astype(np.float32))
    p = DQNParams(total_steps=1000, eps_fraction=0.5, eps_start=1.0, eps_end=0.1)
    assert epsilon_at(p, 0) == 1.0 and epsilon_at(p, 250) == pytest.approx(0.55)
    assert epsilon_at(p, 900) == pytest.approx(0.1)


def test_the_kept_policy_explains_every_decision_it_flies():
    """The default policy (discrete AB) says why: every action's Q value, the runner-up and
    the margin, the same decision as calling it; the flight's pilot records it (issue 29)."""
    from skyherd.flight.state import VehicleState
    from skyherd.mission.pilots import Observation, PolicyPilot
    from skyherd.policy import load_policy
    from skyherd.policy.groundair.env import GroundAirEnv
    from skyherd.policy.models import DEFAULT_POLICY
    from skyherd.task.params import ACTION_NAMES, TaskParams

    pol = load_policy(DEFAULT_POLICY)
    env = GroundAirEnv("composite")
    obs, _ = env.reset(seed=300_000)
    state = VehicleState(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                         np.array([0, 0, -9.81]), False)  # fmt: skip
    seen = set()
    for _ in range(60):
        a = pol(obs)
        ex = pol.explain(obs)
        q = pol.q_values(obs)
        runner_up = sorted(q)[-2]
        assert ex["module"] == "ab_mean" and ex["action"] == ACTION_NAMES[a]
        assert ex["q_values"] == {n: round(float(v), 4) for n, v in zip(ACTION_NAMES, q)}
        assert ex["margin"] == round(float(q[a] - runner_up), 4) and ex["margin"] >= 0
        assert ex["reason"].startswith(f"Q-network chose {ACTION_NAMES[a]} (Q {q[a]:.3f}; ")
        prop = PolicyPilot(pol, TaskParams()).propose(Observation(0.0, state, obs[:8], obs, 0.5))
        assert prop.explanation == ex and prop.action == a
        seen.add(a)
        obs, *_ = env.step(a)
    assert len(seen) >= 3  # several different decisions were explained


def test_explain_breaks_ties_as_the_policy_does_and_refuses_bad_input():
    flat = MLPPolicy([np.zeros((7, 14))], [np.zeros(7)], {})  # every Q equal
    ex = flat.explain(np.zeros(14))
    assert flat(np.zeros(14)) == 0 and ex["action"] == "hover" and ex["margin"] == 0.0
    assert ex["module"] == "policy" and "runner-up north" in ex["reason"]
    grid = MLPPolicy([np.eye(4, 3)], [np.zeros(4)], {"learner": "grid"})
    assert grid.explain(np.array([0.0, 2.0, 1.0]))["action"] == "a1"  # not the task's 7 actions
    with pytest.raises(ValueError, match=r"finite obs of shape \(14,\)"):
        flat.explain(np.full(14, np.nan))
