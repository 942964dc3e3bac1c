"""SQL learners: Q-learning against value iteration, the sharing rule, seeded learning results,
and `skyherd train sql --quick` end to end."""

import csv
import json

import numpy as np
import pytest

from skyherd.policy.sql import (
    Algorithm,
    GridParams,
    SQLHyper,
    build_layout,
    make_layout,
    plan_paths,
    train,
)
from skyherd.policy.sql.kernels import share_max_nonzero
from skyherd.policy.sql.metrics import convergence_episode, moving_average
from skyherd.scripts.cli import main


def value_iteration(lay, h, tol=1e-12):
    """Q* of the single-agent grid world (stay on walls, −1 into obstacles, +10 terminal target)."""
    S = lay.n_cells
    Q = np.zeros((S, 4))
    while True:
        V = Q.max(axis=1)
        V[lay.targets] = 0.0  # terminal
        Qn = np.zeros_like(Q)
        for s in range(S):
            for a in range(4):
                s2 = lay.next_cell[s, a]
                if s2 < 0:
                    Qn[s, a] = h.r_step + h.gamma * V[s]
                elif lay.obstacle[s2]:
                    Qn[s, a] = h.r_collision + h.gamma * V[s]
                elif lay.target_id[s2] >= 0:
                    Qn[s, a] = h.r_goal
                else:
                    Qn[s, a] = h.r_step + h.gamma * V[s2]
        if np.abs(Qn - Q).max() < tol:
            return Qn
        Q = Qn


def test_q_learning_matches_value_iteration_on_tiny_grid():
    # 4×4, start (1,1), target (4,4), obstacles on (2,2) and (3,3): shortest paths of 6 moves
    lay = make_layout(4, [(1, 1)], [(4, 4)], roi_min=4, obstacles_xy=[(2, 2), (3, 3)])
    # ε = 1 throughout (off-policy: Q-learning still learns Q*), no team bonus
    h = SQLHyper(
        episodes=4000,
        max_steps=200,
        eps_start=1.0,
        eps_decay=1.0,
        eps_min=1.0,
        bonus_all=0.0,
        bonus_reached=0.0,
        bonus_missed=0.0,
    )
    res = train(Algorithm.SQL, lay, h, seed=0)
    q_star = value_iteration(lay, h)
    live = [s for s in range(lay.n_cells) if not lay.obstacle[s] and lay.target_id[s] < 0]
    err = np.abs(res.q[0, live] - q_star[live])
    assert err.max() < 1e-3
    # the greedy policy is optimal: 6 moves (Manhattan distance around the obstacles)
    assert np.array_equal(res.q[0, live].argmax(axis=1), q_star[live].argmax(axis=1)) or all(
        q_star[s, res.q[0, s].argmax()] == q_star[s].max() for s in live
    )
    path = plan_paths(res, 1)[0]
    assert len(path) == 7 and path[0] == (1, 1) and path[-1] == (4, 4)
    assert q_star[lay.starts[0]].max() == pytest.approx(10 * 0.9**5)


def test_sharing_rule_on_hand_made_tables():
    q = np.zeros((3, 2, 4))
    q[:, 0, 0] = [0.0, -0.5, 0.0]  # only a negative non-zero value → it wins over the zeros
    q[:, 0, 1] = [1.0, 3.0, -2.0]  # max of the non-zero values
    q[:, 0, 2] = [0.0, 0.0, 0.0]  # all zero → 0
    q[:, 1, 3] = [-1.0, -4.0, 0.0]  # max over non-zero = −1 (the zero is ignored)
    q[:, 1, 0] = [0.0, 2.5, 0.0]
    share_max_nonzero(q)
    expect = np.zeros((2, 4))
    expect[0, 0], expect[0, 1], expect[1, 3], expect[1, 0] = -0.5, 3.0, -1.0, 2.5
    for i in range(3):
        assert np.array_equal(q[i], expect)


def test_sql_sie_learns_the_4_agent_formation_with_a_fixed_seed():
    """Seeded result: SQL-SIE (N = 20) solves K = 4 within 3000 episodes; SQL does not."""
    lay = build_layout(GridParams(n_agents=4))
    h = SQLHyper(episodes=3000, share_every=20)
    sie = train(Algorithm.SQL_SIE, lay, h, seed=0)
    assert sie.metrics.success[-300:].mean() >= 0.9
    assert sie.metrics.steps[-300:].mean() < 150  # shortest is ≈ 2·44 steps
    paths = plan_paths(sie, 4)
    assert sorted(p[-1] for p in paths) == sorted(lay.xy(t) for t in lay.targets)
    for p in paths:  # one grid move at a time, never onto an obstacle
        steps = [abs(x2 - x1) + abs(y2 - y1) for (x1, y1), (x2, y2) in zip(p, p[1:])]
        assert set(steps) <= {0, 1}
        assert not any(lay.obstacle[lay.cell(x, y)] for x, y in p)
    for t in range(len(paths[0])):  # never two agents on one cell
        assert len({p[t] for p in paths}) == 4
    sql = train(Algorithm.SQL, lay, SQLHyper(episodes=3000), seed=0)
    assert sql.metrics.success[-300:].mean() < sie.metrics.success[-300:].mean()


def test_convergence_metric():
    steps = np.r_[np.full(500, 1000.0), np.full(1500, 100.0)]
    # the first 100-episode window with a mean <= 1.1·100 + 1 holds one 1000-step episode
    # (1·1000 + 99·100)/100 = 109: it ends at episode 599
    assert convergence_episode(steps, np.r_[np.zeros(500), np.ones(1500)], 100, 500) == 599
    assert convergence_episode(steps, np.zeros(2000), 100, 500) is None
    assert np.allclose(moving_average(np.arange(5.0), 2), [0.5, 1.5, 2.5, 3.5])


def test_train_sql_quick_end_to_end(tmp_path):
    rc = main(
        [
            "train",
            "sql",
            "--quick",
            "--episodes",
            "300",
            "--seeds",
            "0",
            "1",
            "--experiment",
            "sharing",
            "--sharing-periods",
            "1",
            "5",
            "--runs-dir",
            str(tmp_path),
        ]
    )
    assert rc == 0
    (run,) = list(tmp_path.iterdir())
    cfg = json.loads((run / "config.json").read_text())
    assert (
        cfg["seeds"] == [0, 1] and cfg["hyper"]["alpha"] == 0.1 and cfg["hyper"]["episodes"] == 300
    )
    assert [c["share_every"] for c in cfg["experiments"]["sharing"]] == [1, 5]
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert len(rows) == 4 and {r["share_every"] for r in rows} == {"1", "5"}
    ep = list(csv.DictReader(open(run / "episodes" / "sql-sie_K4_N1_seed0.csv")))
    assert len(ep) == 300 and all(1 <= int(r["steps"]) <= 1000 for r in ep)
    assert (run / "curves_sharing.png").stat().st_size > 10_000
    assert "| sharing" in (run / "results.md").read_text()


def test_train_sql_bad_usage(tmp_path, capsys):
    assert main(["train", "sql", "--agents", "5", "--runs-dir", str(tmp_path)]) == 2
    assert main(["train", "sql", "--episodes", "0", "--runs-dir", str(tmp_path)]) == 2
    assert "K=5" in capsys.readouterr().err
