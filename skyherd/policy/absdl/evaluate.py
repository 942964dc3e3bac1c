"""Evaluation on unseen composite episodes, every policy flown through the safety net as in fly.

For each actor (obs → command (3,) [m/s]) and each episode seed: the composite episode is flown
with the shield certifying every decision (policy.absdl.shield), and measured:

- all_in_view_frac, footprint_ratio: the environment's metrics (policy.groundair.env);
- changed: fraction of decisions whose certified command differs from the proposal;
- jerk [m/s³]: mean over the episode of |a_k − a_{k−1}| / dt with a_k = (c_k − c_{k−1}) / dt
  on the commanded velocity c (the proposal: `jerk_proposed`; the certified command flown:
  `jerk_flown`).

`discrete_actor` turns a discrete policy (the kept AB file) into the same kind of actor: its
action's velocity row (policy.groundair.params.action_velocity_ned), the same dynamics.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skyherd.policy.absdl.demos import rollout
from skyherd.policy.absdl.env import ContinuousGroundAirEnv
from skyherd.policy.absdl.shield import Shield
from skyherd.task.params import TaskParams, action_velocity_ned

METRICS = ("all_in_view_frac", "footprint_ratio", "changed", "jerk_proposed", "jerk_flown")


def jerk(c: np.ndarray, dt: float) -> float:
    """Mean |Δ²c| / dt² over a command sequence c (T, 3) [m/s] → [m/s³] (0 when T < 3)."""
    if len(c) < 3:
        return 0.0
    a = np.diff(c, axis=0) / dt
    return float(np.mean(np.linalg.norm(np.diff(a, axis=0), axis=1)) / dt)


@dataclass(frozen=True)
class Score:
    name: str
    n: int
    mean: dict[str, float]
    std: dict[str, float]
    changed: int
    decisions: int


def evaluate(
    name: str,
    actor: Callable[[np.ndarray], np.ndarray],
    seeds,
    reset: Callable[[int], None] | None = None,
    on_episode: Callable[[], None] | None = None,
) -> Score:
    env = ContinuousGroundAirEnv("composite")
    sh = Shield()
    rows = {m: [] for m in METRICS}
    dt = env.task.dt_s
    for s in seeds:
        if reset is not None:
            reset(int(s))
        before = sh.stats.changed
        ep, _ = rollout(env, actor, int(s), sh)
        rows["all_in_view_frac"].append(ep.metrics["all_in_view_frac"])
        rows["footprint_ratio"].append(ep.metrics["footprint_ratio"])
        rows["changed"].append((sh.stats.changed - before) / len(ep.verdicts))
        rows["jerk_proposed"].append(jerk(ep.proposed, dt))
        rows["jerk_flown"].append(jerk(ep.certified, dt))
        if on_episode is not None:
            on_episode()
    mean = {m: float(np.nanmean(v)) for m, v in rows.items()}
    std = {m: float(np.nanstd(v)) for m, v in rows.items()}
    return Score(name, len(rows["changed"]), mean, std, sh.stats.changed, sh.stats.decisions)


def discrete_actor(policy, task: TaskParams | None = None) -> Callable[[np.ndarray], np.ndarray]:
    uav = (task or TaskParams()).uav
    return lambda o: np.array(action_velocity_ned(int(policy(o)), uav))


def within(a: float, b: float, rel: float) -> bool:
    """|a − b| <= rel · |b| (a within rel of b)."""
    return math.isfinite(a) and math.isfinite(b) and abs(a - b) <= rel * abs(b)
