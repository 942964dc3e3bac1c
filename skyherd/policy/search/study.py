"""The search study (`skyherd study search`): re-acquiring a lost UGV on the speed-off and camouflage
scenarios (GroundAir env, groundsim:speedoff / groundsim:camouflage), 50 unseen episodes each
(seeds 400000+), for the scripted expert and today's policy (policy/models/groundair_ab.npz),
each without and with the search (policy.search.lost).

The UGV watched is the scenario's escaping or camouflaged one (the last; the evaluation knows
it, the pilot does not). It is lost when it first leaves the view after being seen, and
re-acquired when it is in view again before the episode's end (60 s; every pilot flies the
whole episode: SEARCH_TASK). Printed per (pilot, scenario): the episodes it was lost in, the
fraction of those where it was re-acquired, the median and 90th-percentile time to re-acquire,
the fraction of the time after its loss it was in view, and the fraction of the episode with
every UGV in view. `run` writes table.md and episodes.csv into `out`.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.policy.search.lost import LostSearch
from skyherd.task.params import TaskParams

SCENARIOS = ("groundsim:speedoff", "groundsim:camouflage")
FIRST_SEED = 400_000
SEARCH_TASK = TaskParams(lost_s=TaskParams().episode_s)
"""The training env ends an episode after 2 s with no UGV in view; a search needs longer, so
here every pilot, with and without the search, flies the whole 60 s."""


def run_episode(env: GroundAirEnv, act, seed: int, search: bool) -> dict:
    """One episode; act: obs → action (the base pilot). Returns the target UGV's (the last
    one: the scenario's escaping or camouflaged UGV) first loss and re-acquisition times [s]
    (None: never lost / never back), the fraction of the time after its loss it was in view,
    and the episode's all-in-view fraction."""
    obs, _ = env.reset(seed=seed)
    pilot = LostSearch(act, env.task) if search else None
    dt, target = env.task.dt_s, env.task.n_ugvs - 1
    t, done, seen_hist, info = 0.0, False, [], {}
    while not done:
        ugvs = env.formation.positions()
        _, seen, _ = env.cam.phi(env.n, env.e, env.alt, ugvs, env.formation.detectable())
        seen_hist.append(bool(seen[target]))
        if pilot is None:
            a = int(act(obs))
        else:
            uav = np.array([env.n, env.e, -env.alt])
            a = pilot.act(obs, t, uav, {i: np.array(ugvs[i]) for i, s in enumerate(seen) if s})
        obs, _, term, trunc, info = (
            env.step_velocity(a) if isinstance(a, np.ndarray) else env.step(a)
        )
        t += dt
        done = term or trunc
    h = np.array(seen_hist)
    t_lost = t_back = None
    first_seen = np.flatnonzero(h)
    if len(first_seen):
        gone = np.flatnonzero(~h[first_seen[0] :]) + first_seen[0]
        if len(gone):
            t_lost = float(gone[0] * dt)
            back = np.flatnonzero(h[gone[0] :]) + gone[0]
            t_back = float(back[0] * dt) if len(back) else None
    after = float(h[int(round(t_lost / dt)) :].mean()) if t_lost is not None else 1.0
    return {"t_lost": t_lost, "t_back": t_back, "in_view_after": after,
            "all_in_view": info["metrics"]["all_in_view_frac"]}  # fmt: skip


def pilots() -> dict:
    from skyherd.policy.demos import ExpertParams, scripted_expert
    from skyherd.policy.dqn import load_policy
    from skyherd.policy.models import DEFAULT_POLICY

    pol = load_policy(DEFAULT_POLICY)
    return {"expert": lambda s: scripted_expert("composite", ExpertParams(), seed=s),
            "policy (groundair_ab)": lambda s: pol}  # fmt: skip


def run(
    episodes: int = 50, first_seed: int = FIRST_SEED, out: str | Path | None = None
) -> list[dict]:
    rows = []
    for name, make in pilots().items():
        for sc in SCENARIOS:
            env = GroundAirEnv(sc, task=SEARCH_TASK)
            for search in (False, True):
                seeds = range(first_seed, first_seed + episodes)
                eps = [dict(run_episode(env, make(s), s, search), seed=s) for s in seeds]
                lost = [e for e in eps if e["t_lost"] is not None]
                back = [e["t_back"] - e["t_lost"] for e in lost if e["t_back"] is not None]
                rows.append({"pilot": name + (" + search" if search else ""), "scenario": sc.split(":")[1],
                             "episodes": episodes, "lost": len(lost),
                             "reacquired": len(back) / max(len(lost), 1),
                             "median_s": float(np.median(back)) if back else float("nan"),
                             "p90_s": float(np.percentile(back, 90)) if back else float("nan"),
                             "in_view_after": float(np.mean([e["in_view_after"] for e in lost])) if lost else 1.0,
                             "all_in_view": float(np.mean([e["all_in_view"] for e in eps])), "_eps": eps})  # fmt: skip
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(table(rows) + "\n")
        with open(out / "episodes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(
                [
                    "pilot",
                    "scenario",
                    "seed",
                    "t_lost_s",
                    "t_back_s",
                    "in_view_after",
                    "all_in_view",
                ]
            )
            for r in rows:
                for e in r["_eps"]:
                    w.writerow([r["pilot"], r["scenario"], e["seed"], e["t_lost"], e["t_back"],
                                round(e["in_view_after"], 4), round(e["all_in_view"], 4)])  # fmt: skip
    return rows


def table(rows: list[dict]) -> str:
    out = ["| pilot | scenario | episodes it was lost | re-acquired | median time to re-acquire [s] | p90 [s] | "
           "its time in view after the loss | all in view |", "| --- | --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for r in rows:
        out.append(f"| {r['pilot']} | {r['scenario']} | {r['lost']}/{r['episodes']} | {r['reacquired']:.2f} "
                   f"| {r['median_s']:.1f} | {r['p90_s']:.1f} | {r['in_view_after']:.3f} | {r['all_in_view']:.3f} |")  # fmt: skip
    return "\n".join(out)
