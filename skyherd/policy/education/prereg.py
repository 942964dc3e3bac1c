"""Pre-registered evaluation of issue 14's composite goals on 100 fresh unseen episodes.

The rule was fixed before the run (session 5, edu3):
  episodes: composite, env seeds 700000..700099 (no one used them before);
  metrics: `policy.demos.rollout_stats`, the same code and gamma (0.97) as `skyherd educate`'s
  unseen-episode table, called once per episode so the per-episode standard error can be given;
  goal 1 holds iff all_in_view(educated) >= 0.98 * all_in_view(AB);
  goal 2 holds iff |fp(educated) - fp(expert)| < |fp(AB) - fp(expert)|.
With several educated seed policies, their mean over policies is the educated figure.

Run: skyherd evaluate EDUCATED.npz... --ab AB.npz (scripts/evaluate.py)
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

import numpy as np

SCENARIO = "composite"
FIRST_SEED = 700_000
N_EPISODES = 100
GAMMA = 0.97  # EduParams().dqn.gamma, as in the educate run's config.json
KEYS = ("all_in_view_frac", "footprint_ratio")


def per_episode(
    act, first: int = FIRST_SEED, n: int = N_EPISODES, on_episode: Callable[[], None] | None = None
) -> list[dict[str, float]]:
    """One `rollout_stats` call per episode (seeds first..first+n-1); `on_episode()` after each."""
    from skyherd.policy.demos import rollout_stats

    out = []
    for k in range(n):
        out.append(rollout_stats(act, SCENARIO, 1, first + k, GAMMA)[1])
        if on_episode is not None:
            on_episode()
    return out


def summarise(eps: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """Mean (NaN episodes left out, as rollout_stats does) and standard error over episodes."""
    out = {}
    for key in KEYS:
        v = np.array([e[key] for e in eps if not math.isnan(e[key])])
        se = float(v.std(ddof=1) / math.sqrt(len(v))) if len(v) > 1 else math.nan
        out[key] = {"mean": float(v.mean()), "se": se, "n": int(len(v))}
    return out


def verdicts(edu: dict, ab: dict, expert: dict) -> dict[str, bool]:
    a = "all_in_view_frac"
    f = "footprint_ratio"
    return {
        "goal1_all_in_view": edu[a] >= 0.98 * ab[a],
        "goal2_footprint": abs(edu[f] - expert[f]) < abs(ab[f] - expert[f]),
    }


def evaluate(educated: list[Path], ab: Path, on_episode: Callable[[], None] | None = None) -> dict:
    """The pre-registered evaluation of `educated` policies (.npz, one per seed) against the
    kept AB policy and the scripted expert: per-episode figures, their summaries, the verdicts.
    `on_episode()` runs after each of the (len(educated) + 2) * N_EPISODES episodes."""
    from skyherd.policy.demos import ExpertParams, scripted_expert
    from skyherd.policy.dqn import load_policy

    def run(act) -> list[dict[str, float]]:
        return per_episode(act, on_episode=on_episode)

    eps = {f"educated:{f.stem}": run(load_policy(f)) for f in educated}
    eps["ab"] = run(load_policy(ab))
    eps["expert"] = run(scripted_expert(SCENARIO, ExpertParams(), 0))
    summ = {k: summarise(v) for k, v in eps.items()}
    edu_keys = [k for k in summ if k.startswith("educated:")]
    edu = {m: float(np.mean([summ[k][m]["mean"] for k in edu_keys])) for m in KEYS}
    means = {k: {m: summ[k][m]["mean"] for m in KEYS} for k in ("ab", "expert")}
    return {
        "rule": __doc__,
        "seeds": [FIRST_SEED, FIRST_SEED + N_EPISODES - 1],
        "summary": summ,
        "educated_mean_over_policies": edu,
        "verdicts": verdicts(edu, means["ab"], means["expert"]),
        "per_episode": eps,
    }
