"""Swarm Q-learning for formation control: SQL, SQL-D and SQL-SIE on the seed's grid world.

See docs/sql.md. Entry points: `build_layout`, `train`, `greedy_rollout`, `plan_paths`,
`learn_plan` (the formation's plan), `FormationEnv` (the same rules, one step at a time,
PettingZoo parallel-style).
"""

from skyherd.policy.sql.env import FormationEnv
from skyherd.policy.sql.layout import Layout, build_layout, make_layout
from skyherd.policy.sql.metrics import RunSummary, convergence_episode, summarize
from skyherd.policy.sql.params import Algorithm, GridParams, PlanParams, SQLHyper
from skyherd.policy.sql.train import (
    Metrics,
    TrainResult,
    greedy_rollout,
    learn_plan,
    plan_paths,
    train,
)

__all__ = [
    "Algorithm",
    "FormationEnv",
    "GridParams",
    "Layout",
    "Metrics",
    "PlanParams",
    "RunSummary",
    "SQLHyper",
    "TrainResult",
    "build_layout",
    "convergence_episode",
    "greedy_rollout",
    "learn_plan",
    "make_layout",
    "plan_paths",
    "summarize",
    "train",
]
