"""The formation's learned plan (policy.sql.learn_plan) without the command line: SQL-SIE on the
built-in layout, its greedy paths, the same plan from the same seed, and where it came from."""

from __future__ import annotations

import pytest

from skyherd.policy.sql import GridParams, PlanParams, SQLHyper, build_layout, learn_plan

# 3,000 episodes solve K = 4 with seed 0 (tests/policy/test_sql_learning.py); the command
# learns with the study's 10,000.
PARAMS = PlanParams(GridParams(n_agents=4), SQLHyper(episodes=3000), seed=0)


@pytest.fixture(scope="module")
def plan():
    ticks = []
    out = learn_plan(PARAMS, ticks.append)
    assert sum(ticks) == PARAMS.hyper.episodes  # progress: every episode once
    return out


def test_the_plan_is_lockstep_one_cell_at_a_time_onto_the_targets(plan):
    layout = build_layout(PARAMS.grid)
    assert len(plan) == 4 and len({len(p) for p in plan}) == 1
    assert [p[0] for p in plan] == [layout.xy(int(s)) for s in layout.starts]
    assert sorted(p[-1] for p in plan) == sorted(layout.xy(int(t)) for t in layout.targets)
    for p in plan:
        assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) <= 1 for a, b in zip(p, p[1:]))
        assert all(isinstance(v, int) for c in p for v in c)  # JSON-ready cells
    for t in range(len(plan[0])):
        assert len({p[t] for p in plan}) == 4  # never two agents on one cell


def test_the_same_params_learn_the_same_plan(plan):
    assert learn_plan(PARAMS) == plan


def test_only_the_built_in_layouts_and_a_seed_from_zero():
    with pytest.raises(ValueError, match="no built-in layout for K = 5"):
        learn_plan(PlanParams(GridParams(n_agents=5)))
    with pytest.raises(ValueError, match="seed must be >= 0"):
        PlanParams(seed=-1)


def test_describe_says_where_the_plan_came_from():
    d = PlanParams(GridParams(n_agents=9), seed=3).describe()
    assert d["source"] == "trained" and d["algorithm"] == "sql-sie" and d["seed"] == 3
    assert d["grid"]["n_agents"] == 9 and d["hyper"]["episodes"] == SQLHyper().episodes
