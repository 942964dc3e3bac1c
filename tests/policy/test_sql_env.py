"""SQL grid world: layout, every environment rule, team bonus values, seeded determinism."""

import numpy as np
import pytest

from skyherd.policy.sql import (
    Algorithm,
    FormationEnv,
    GridParams,
    SQLHyper,
    build_layout,
    greedy_rollout,
    make_layout,
    plan_paths,
    train,
)
from skyherd.policy.sql.layout import STARTS
from skyherd.policy.sql.train import _call

UP, DOWN, LEFT, RIGHT = 0, 1, 2, 3


@pytest.mark.parametrize("K,roi", [(4, 45), (9, 45), (16, 43)])
def test_built_in_layouts(K, roi):
    lay = build_layout(GridParams(n_agents=K, map_seed=3))
    xy = [lay.xy(s) for s in range(lay.n_cells)]
    assert lay.obstacle.sum() == 50  # 2 % of 2500
    obst = [xy[s] for s in np.flatnonzero(lay.obstacle)]
    assert all(not (x >= roi and y >= roi) for x, y in obst)  # never in the ROI
    assert not set(obst) & set(STARTS[K])  # never on a start
    assert lay.n_roi == (51 - roi) ** 2
    assert len(lay.targets) == K and all(lay.roi_id[t] >= 0 for t in lay.targets)
    if K == 9:
        assert [lay.xy(s) for s in lay.starts] == list(STARTS[9])
        assert {lay.xy(t) for t in lay.targets} == {
            (x, y) for x in (46, 48, 50) for y in (46, 48, 50)
        }
    if K == 16:
        assert {lay.xy(t) for t in lay.targets} == {
            (x, y) for x in (44, 46, 48, 50) for y in (44, 46, 48, 50)
        }
    # same map seed → same map; different seed → different map
    assert np.array_equal(lay.obstacle, build_layout(GridParams(n_agents=K, map_seed=3)).obstacle)
    assert not np.array_equal(
        lay.obstacle, build_layout(GridParams(n_agents=K, map_seed=4)).obstacle
    )


def _env(**kw):
    #  y=3  .  .  T
    #  y=2  .  #  .
    #  y=1  A  B  .      (x = 1..3)
    lay = make_layout(3, [(1, 1), (2, 1)], [(3, 3), (1, 3)], roi_min=3, obstacles_xy=[(2, 2)])
    return FormationEnv(lay, SQLHyper(**kw)), lay


def test_walls_obstacles_agents_and_targets():
    env, lay = _env(max_steps=50)
    obs, _ = env.reset()
    assert list(obs["agent_0"]) == [1, 1] and list(obs["agent_1"]) == [2, 1]
    assert env.observation_space("agent_0").contains(obs["agent_0"])
    assert env.action_space("agent_1").n == 4 and env.agents == env.possible_agents
    # agent_0 left into the wall: stays, no penalty; agent_1 up into the obstacle: stays, −1
    obs, rew, term, trunc, info = env.step({"agent_0": LEFT, "agent_1": UP})
    assert list(obs["agent_0"]) == [1, 1] and rew["agent_0"] == 0.0
    assert info["agent_0"]["outcome"] == "wall"
    assert list(obs["agent_1"]) == [2, 1] and rew["agent_1"] == -1.0
    assert info["agent_1"]["outcome"] == "obstacle"
    # agent_0 right into agent_1: stays, no penalty; down off the grid is also a wall
    obs, rew, *_, info = env.step({"agent_0": RIGHT, "agent_1": DOWN})
    assert list(obs["agent_0"]) == [1, 1] and rew["agent_0"] == 0.0
    assert info["agent_0"]["outcome"] == "agent" and info["agent_1"]["outcome"] == "wall"
    # sequential moves: agent_1 leaves (2,1) after agent_0 tried to enter it → agent_0 stayed
    obs, *_, info = env.step({"agent_0": RIGHT, "agent_1": RIGHT})
    assert list(obs["agent_0"]) == [1, 1] and list(obs["agent_1"]) == [3, 1]
    # agent_0 up to (1,2), agent_1 up to (3,2)
    env.step({"agent_0": UP, "agent_1": UP})
    # both reach targets: +10 each, stop, and the team bonus +10 lands on their last reward
    obs, rew, term, trunc, info = env.step({"agent_0": UP, "agent_1": UP})
    assert term == {"agent_0": True, "agent_1": True}
    assert rew == {"agent_0": 20.0, "agent_1": 20.0}
    assert env.agents == []
    with pytest.raises(RuntimeError):
        env.step({})


def test_stopped_agent_blocks_its_target_and_bonus_when_not_all_reach():
    env, lay = _env(max_steps=3)
    env.reset()
    # a0 moves first and frees (1,1), so a1 can take it within the same step
    obs, *_ = env.step({"agent_0": UP, "agent_1": LEFT})
    assert list(obs["agent_0"]) == [1, 2] and list(obs["agent_1"]) == [1, 1]
    obs, rew, term, *_ = env.step({"agent_0": UP, "agent_1": UP})  # a0 on target (1,3)
    assert term["agent_0"] and rew["agent_0"] == 10.0 and env.agents == ["agent_1"]
    # the last allowed step: a1 bumps into a0 standing on its target → stays, no penalty;
    # truncation, and the team bonus: −1 for a0 (reached), −2 for a1 (did not)
    obs, rew, term, trunc, info = env.step({"agent_1": UP})
    assert list(obs["agent_1"]) == [1, 2] and info["agent_1"]["outcome"] == "agent"
    assert trunc["agent_1"] and not term["agent_1"]
    assert rew["agent_1"] == -2.0 and rew["agent_0"] == -1.0
    assert info["agent_0"]["team_bonus"] == -1.0


def test_bad_actions_rejected():
    env, _ = _env()
    env.reset()
    with pytest.raises(ValueError):
        env.step({"agent_0": 7, "agent_1": 0})
    with pytest.raises(ValueError):
        env.step({"agent_0": 0})


def _run_sql_once(lay, h, q):
    """One greedy learning episode of the SQL kernel through the trainer's own call."""
    eps, rng, no_paths = np.zeros(1), np.array([1], np.uint64), np.zeros((0, 0), np.int32)
    return _call(Algorithm.SQL, lay, h, q, None, eps, True, rng, 0, no_paths)


def test_kernel_team_bonus_values():
    """SQL kernel: a 1-step reach gives Q = α·10 then + α·bonus on the same (s, a)."""
    # one row: A . T   with the agent's Q forcing "right"
    lay = make_layout(3, [(2, 1)], [(3, 1)], roi_min=3)
    h = SQLHyper(episodes=1, max_steps=5, eps_start=0.0, eps_min=0.0)
    q = np.zeros((1, 9, 4))
    q[0, lay.cell(2, 1), RIGHT] = 1e-9  # greedy picks right
    out = _run_sql_once(lay, h, q)
    # Q = 1e-9 + 0.1(10 − 1e-9) = ≈1.0, plus 0.1·10 team bonus = ≈2.0
    assert q[0, lay.cell(2, 1), RIGHT] == pytest.approx(2.0, abs=1e-8)
    assert out[0][0] == 1 and out[1][0] and out[2][0] == 1

    # two agents, one target: one reaches (+α·10, bonus −1), the other can't (bonus −2)
    lay = make_layout(3, [(2, 1), (1, 3)], [(3, 1), (3, 3)], roi_min=3, obstacles_xy=[(2, 3)])
    q = np.zeros((2, 9, 4))
    q[0, lay.cell(2, 1), RIGHT] = 1e-9
    q[1, lay.cell(1, 3), RIGHT] = 1e-9  # into the obstacle: −1, stays
    h = SQLHyper(max_steps=1, eps_start=0.0, eps_min=0.0)
    out = _run_sql_once(lay, h, q)
    assert q[0, lay.cell(2, 1), RIGHT] == pytest.approx(1.0 - 0.1, abs=1e-8)
    # agent 1: one −1 collision (max over its row is Q itself = 1e-9), then the −2 bonus
    v = 1e-9 + 0.1 * (-1 + 0.9 * 1e-9 - 1e-9)
    assert q[1, lay.cell(1, 3), RIGHT] == pytest.approx(v - 0.2, abs=1e-12)
    assert out[3][0] == 1 and out[0][0] == 1 and not out[1][0] and out[2][0] == 1


def test_sie_phases_claim_nearest_target_and_stay_in_roi():
    """SQL-SIE greedy replay on a hand-set table: entering the ROI, nearest target, stop."""
    # 4×4 grid, ROI x,y >= 3, targets (4,4) and (3,3); one agent at (1,3) heading right
    lay = make_layout(4, [(1, 3)], [(4, 4)], roi_min=3)
    h = SQLHyper(max_steps=20, eps_start=0.0, eps_min=0.0)
    q1 = np.zeros((1, 16, 4))
    q1[0, lay.cell(1, 3), RIGHT] = q1[0, lay.cell(2, 3), RIGHT] = 1.0
    q2 = np.zeros((1, lay.n_roi, 4))
    q2[0, lay.roi_id[lay.cell(3, 3)], LEFT] = 5.0  # leaving the ROI is a wall: stays
    q2[0, lay.roi_id[lay.cell(3, 3)], UP] = 1.0
    q2[0, lay.roi_id[lay.cell(3, 4)], RIGHT] = 1.0
    from skyherd.policy.sql.train import Metrics, TrainResult

    z = np.zeros(1)
    res = TrainResult(Algorithm.SQL_D, lay, h, 0, Metrics(z, z, z, z, z), q1, q2)
    paths, m = greedy_rollout(res)
    cells = [lay.xy(s) for s in paths[0]]
    # LEFT out of the ROI keeps it on (3,3) forever: the agent never arrives
    assert cells[:3] == [(1, 3), (2, 3), (3, 3)] and set(cells[3:]) == {(3, 3)}
    assert not m.success[0]
    q2[0, lay.roi_id[lay.cell(3, 3)], LEFT] = 0.0
    paths, m = greedy_rollout(res)
    assert [lay.xy(s) for s in paths[0]] == [(1, 3), (2, 3), (3, 3), (3, 4), (4, 4)]
    assert m.success[0] and m.steps[0] == 4
    assert plan_paths(res, 1) == [[(1, 3), (2, 3), (3, 3), (3, 4), (4, 4)]]
    with pytest.raises(ValueError):
        plan_paths(res, 2)


def test_seeded_runs_are_deterministic():
    lay = build_layout(GridParams(n_agents=4))
    h = SQLHyper(episodes=300)
    for alg in Algorithm:
        a = train(alg, lay, h, seed=7)
        b = train(alg, lay, h, seed=7)
        c = train(alg, lay, h, seed=8)
        assert np.array_equal(a.q, b.q) and np.array_equal(a.metrics.steps, b.metrics.steps)
        assert not np.array_equal(a.q, c.q)


def test_bad_hyper_parameters_rejected():
    with pytest.raises(ValueError):
        SQLHyper(alpha=0.0)
    with pytest.raises(ValueError):
        SQLHyper(gamma=1.0)
    with pytest.raises(ValueError):
        SQLHyper(alpha=float("nan"))
    with pytest.raises(ValueError):
        GridParams(obstacle_fraction=float("nan"))
    with pytest.raises(ValueError):
        build_layout(GridParams(n_agents=5))
    with pytest.raises(ValueError):
        train(Algorithm.SQL_SIE, build_layout(GridParams(n_agents=4)), SQLHyper(share_every=0))
