"""Training driver: runs a learner's kernel in chunks, keeps its Q tables and per-episode metrics.

`train` is the one entry point for SQL, SQL-D and SQL-SIE; `greedy_rollout` / `plan_paths`
replay the learned policy without exploration or learning (for evaluation and for flying the
formation later); `learn_plan` trains SQL-SIE and returns the plan the formation flies.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skyherd.policy.sql import kernels
from skyherd.policy.sql.kernels import rng_state
from skyherd.policy.sql.layout import STARTS, Layout, build_layout
from skyherd.policy.sql.params import Algorithm, PlanParams, RoiPretrain, Rules, SQLHyper
from skyherd.policy.sql.roitable import fixed_roi_table, pretrained_roi_tables

__all__ = [
    "Metrics", "TrainResult", "fixed_roi_table", "greedy_rollout", "learn_plan", "plan_paths",
    "pretrained_roi_tables", "rng_state", "train",
]  # fmt: skip

CHUNK = 100
"""Episodes per kernel call (one progress-bar tick)."""


@dataclass(frozen=True, eq=False)
class Metrics:
    """Per-episode metrics, each of shape (E,)."""

    steps: np.ndarray
    """Largest number of steps any agent took (capped at max_steps)."""
    success: np.ndarray
    """All agents reached targets (bool)."""
    reached: np.ndarray
    """Number of agents on targets at the end."""
    collisions: np.ndarray
    """Obstacle collisions (all agents)."""
    agent_steps: np.ndarray
    """Moves taken, summed over agents (the work done by the kernel)."""


@dataclass(frozen=True, eq=False)
class TrainResult:
    """A trained learner: its tables, metrics and everything needed to replay it."""

    algorithm: Algorithm
    layout: Layout
    hyper: SQLHyper
    seed: int
    metrics: Metrics
    q: np.ndarray
    """SQL: (K, S, 4) per-agent tables; SQL-D / SQL-SIE: (K, S, 4) phase-1 tables."""
    q_target: np.ndarray | None
    """SQL-D / SQL-SIE: (T, R, 4) per-target tables over ROI cells; None for SQL."""
    rules: Rules = Rules()
    """The rule variants the run followed."""


def _call(algorithm, layout, hyper, q, q2, eps, learn, rng, episode0, paths, rules=None):
    rules = rules or Rules()
    first = rules.ties == "first"
    E = eps.shape[0]
    out = (
        np.zeros(E, np.int64),
        np.zeros(E, np.bool_),
        np.zeros(E, np.int64),
        np.zeros(E, np.int64),
        np.zeros(E, np.int64),
    )
    h = hyper
    if algorithm is Algorithm.SQL:
        kernels.run_sql(
            layout.next_cell,
            layout.obstacle,
            layout.target_id,
            layout.roi_id,
            layout.starts,
            q,
            eps,
            h.alpha,
            h.gamma,
            h.max_steps,
            h.r_step,
            h.r_collision,
            h.r_goal,
            h.bonus_all,
            h.bonus_reached,
            h.bonus_missed,
            first,
            rules.team_bonus == "blend",
            rules.q_form == "blend",
            learn,
            rng,
            *out,
            paths,
        )
    else:
        share = h.share_every if algorithm is Algorithm.SQL_SIE else 0
        kernels.run_sie(
            layout.next_cell,
            layout.obstacle,
            layout.roi_id,
            layout.targets,
            layout.starts,
            q,
            q2,
            eps,
            h.alpha,
            h.gamma,
            h.max_steps,
            h.r_step,
            h.r_collision,
            h.r_goal,
            share,
            episode0,
            first,
            rules.roi_phase == "pretrained",
            rules.assign == "q-argmax",
            rules.step_count == "published",
            rules.assign_cell == "agents-1-2",
            rules.walk_draws == "per-move",
            rules.walk_end == "step-onto",
            rules.q_form == "blend",
            learn,
            rng,
            *out,
            paths,
        )
    return out


def train(
    algorithm: Algorithm,
    layout: Layout,
    hyper: SQLHyper,
    seed: int = 0,
    progress: Callable[[int], None] | None = None,
    rules: Rules | None = None,
    pretrain: RoiPretrain | None = None,
) -> TrainResult:
    """Train for hyper.episodes episodes; `progress(n)` is called after every n episodes.

    `rules` (default `Rules()`, the intended set) picks the rule variants; with
    rules.roi_phase == "pretrained" the per-target ROI tables are kept fixed through the run:
    rules.roi_table "fixed" (published) loads the formation's one table (`fixed_roi_table`,
    seeded by `pretrain.seed`, the same for every run), "per-run" pre-trains new ones first
    from the run's own random stream (`pretrained_roi_tables`); settings `pretrain`.
    """
    rules = rules or Rules()
    algorithm = Algorithm(algorithm)
    if algorithm is Algorithm.SQL_SIE and hyper.share_every < 1:
        raise ValueError("SQL-SIE needs share_every >= 1 (share_every = 0 is SQL-D)")
    K, S = layout.n_agents, layout.n_cells
    if layout.targets.shape[0] != K:
        raise ValueError(f"{K} agents but {layout.targets.shape[0]} targets")
    q = np.zeros((K, S, 4))
    rng = rng_state(seed)
    q2 = None
    if algorithm is not Algorithm.SQL:
        pre = pretrain or RoiPretrain()
        if rules.roi_phase == "pretrained" and rules.roi_table == "fixed":
            q2 = fixed_roi_table(layout, hyper, rules, pre)
        elif rules.roi_phase == "pretrained":
            q2 = pretrained_roi_tables(layout, hyper, rules, rng, pre)
        else:
            q2 = np.zeros((K, layout.n_roi, 4))
    cols = [[], [], [], [], []]
    no_paths = np.zeros((0, 0), np.int32)
    for e0 in range(0, hyper.episodes, CHUNK):
        n = min(CHUNK, hyper.episodes - e0)
        eps = hyper.epsilons(e0, n, rules.eps_schedule == "stop-decay")
        out = _call(algorithm, layout, hyper, q, q2, eps, True, rng, e0, no_paths, rules)
        for c, o in zip(cols, out):
            c.append(o)
        if progress is not None:
            progress(n)
    metrics = Metrics(*(np.concatenate(c) for c in cols))
    return TrainResult(algorithm, layout, hyper, int(seed), metrics, q, q2, rules)


def greedy_rollout(result: TrainResult, seed: int = 0) -> tuple[np.ndarray, Metrics]:
    """One episode with ε = 0 and no learning on copies of the tables.

    Returns the (K, T+1) cell history (a finished agent keeps its last cell) and the
    episode's metrics. Ties between equal Q values are broken by `seed`.
    """
    q = result.q.copy()
    q2 = None if result.q_target is None else result.q_target.copy()
    T = result.hyper.max_steps
    paths = np.full((result.layout.n_agents, T + 1), -1, np.int32)
    out = _call(
        result.algorithm,
        result.layout,
        result.hyper,
        q,
        q2,
        np.zeros(1),
        False,
        rng_state(seed),
        0,
        paths,
        result.rules,
    )
    n = int(out[0][0])
    paths = paths[:, : n + 1]
    for i in range(paths.shape[0]):  # forward-fill agents that stopped early
        for t in range(1, paths.shape[1]):
            if paths[i, t] < 0:
                paths[i, t] = paths[i, t - 1]
    return paths, Metrics(*out)


def plan_paths(result: TrainResult, K: int, seed: int = 0) -> list[list[tuple[int, int]]]:
    """Per-agent grid paths of the learned greedy policy, 1-based (x, y) cells.

    Element i is agent i's cell after each global step t = 0..T (t = 0 is its start), all
    lists the same length T+1, so the paths stay in step with each other (a repeated cell is
    a wait, or the agent standing on its target). Raises ValueError if K is not the trained
    swarm's size or if the greedy policy does not bring every agent to a target within
    max_steps (the plan would not be a formation).
    """
    if K != result.layout.n_agents:
        raise ValueError(f"result was trained for K={result.layout.n_agents}, not K={K}")
    if result.algorithm is not Algorithm.SQL and result.rules.roi_phase == "pretrained":
        raise ValueError(
            "the published ROI walk moves an agent several cells in one step through other "
            "agents: no flyable plan; train with roi_phase='online' (--rules intended)"
        )
    paths, m = greedy_rollout(result, seed)
    if not bool(m.success[0]):
        raise ValueError(
            f"the greedy policy brings {int(m.reached[0])}/{K} agents to targets in "
            f"{result.hyper.max_steps} steps; train longer before flying it"
        )
    return [[result.layout.xy(int(s)) for s in row] for row in paths]


def learn_plan(
    params: PlanParams, progress: Callable[[int], None] | None = None
) -> list[list[tuple[int, int]]]:
    """The formation's lock-step plan: SQL-SIE trained on the built-in layout of K =
    params.grid.n_agents agents (intended rules), then its greedy paths (`plan_paths`);
    `progress(n)` as in `train`. ValueError if K has no built-in layout or if the greedy policy
    leaves an agent off its target (another seed may succeed). Same params, same plan."""
    K = params.grid.n_agents
    if K not in STARTS:
        raise ValueError(f"no built-in layout for K = {K}: the learned plans are for K = "
                         f"{', '.join(map(str, STARTS))}")  # fmt: skip
    layout = build_layout(params.grid)
    res = train(Algorithm.SQL_SIE, layout, params.hyper, seed=params.seed, progress=progress)
    return plan_paths(res, K)
