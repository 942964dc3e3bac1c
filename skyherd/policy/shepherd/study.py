"""The shepherding study (`skyherd study shepherd`): the learned selector against Strömbom's
hand-written shepherd on the same seeds (0 .. N−1; the learned selector was fitted on seeds 1000+).

Prints, per selector: success rate (the flock's centre inside the goal region within the time
limit) with its 95 % Clopper–Pearson interval, median and 90th-percentile time to goal over the
successes, the mean spread at the end, and how often the two chose alike; `run` writes table.md
and episodes.csv into `out` (the command line adds the figure: scripts/study.py).
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from skyherd.groundsim.flock import FlockParams
from skyherd.policy.shepherd.episode import run_episode
from skyherd.policy.shepherd.rules import ShepherdParams
from skyherd.policy.shepherd.selector import StrombomSelector, make_selector


def clopper_pearson(k: int, n: int, alpha: float = 0.05) -> tuple[float, float]:
    """Exact binomial interval for k successes in n."""
    from scipy.stats import beta

    lo = 0.0 if k == 0 else float(beta.ppf(alpha / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1 - alpha / 2, k + 1, n - k))
    return lo, hi


def summarise(eps) -> dict:
    times = [e.time_to_goal_s for e in eps if e.success]
    k, n = len(times), len(eps)
    lo, hi = clopper_pearson(k, n)
    return {"episodes": n, "success": k, "rate": k / n, "ci": (lo, hi),
            "median_s": float(np.median(times)) if times else float("nan"),
            "p90_s": float(np.percentile(times, 90)) if times else float("nan"),
            "spread_end_m": float(np.mean([e.spread_end_m for e in eps])),
            "drive_fraction": float(np.mean([e.drive_fraction for e in eps]))}  # fmt: skip


def study_flock(n: int, neighbours: int | None = None) -> FlockParams:
    """The study's flock of `n` agents, each steering by the centre of mass of `neighbours`
    others: by default the kept number for the default flock size, n − 1 for any other n (the
    kept 6 lets a larger flock split). ValueError if FlockParams refuses them."""
    d = FlockParams()
    if neighbours is None:
        neighbours = d.neighbours if n == d.n else n - 1
    return FlockParams(n=n, neighbours=neighbours)


def selectors(selector_file: str | None = None) -> dict:
    """The two selectors compared: Strömbom's and the learned one (default: the kept file)."""
    return {"strombom": StrombomSelector(), "learned": make_selector("learned", selector_file)}


def table(rows: dict[str, dict]) -> str:
    out = ["| selector | success | rate (95 % CI) | median time to goal [s] | p90 [s] | "
           "mean end spread [m] | drive decisions |",
           "| --- | --- | --- | --- | --- | --- | --- |"]  # fmt: skip
    for name, s in rows.items():
        lo, hi = s["ci"]
        out.append(f"| {name} | {s['success']}/{s['episodes']} | {s['rate']:.2f} ({lo:.2f}–{hi:.2f}) "
                   f"| {s['median_s']:.1f} | {s['p90_s']:.1f} | {s['spread_end_m']:.2f} "
                   f"| {s['drive_fraction']:.2f} |")  # fmt: skip
    return "\n".join(out)


def run(seeds: int = 100, first_seed: int = 0, out: str | Path | None = "runs/shepherd_study",
        selector_file: str | None = None, flock: FlockParams | None = None,
        episodes: dict | None = None) -> dict:  # fmt: skip
    """Both selectors on seeds first_seed .. first_seed+seeds−1; returns {name: summary}.
    `episodes`, a dict, receives {name: [Episode]} (for a figure)."""
    flock, task = flock if flock is not None else FlockParams(), ShepherdParams()
    sels = selectors(selector_file)
    eps = {name: [run_episode(s, sel, flock, task) for s in range(first_seed, first_seed + seeds)]
           for name, sel in sels.items()}  # fmt: skip
    rows = {name: summarise(e) for name, e in eps.items()}
    if out is not None:
        out = Path(out)
        out.mkdir(parents=True, exist_ok=True)
        (out / "table.md").write_text(table(rows) + "\n")
        with open(out / "episodes.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["selector", "seed", "success", "time_to_goal_s", "spread_start_m",
                        "spread_end_m", "drive_fraction"])  # fmt: skip
            for name, es in eps.items():
                for e in es:
                    w.writerow([name, e.seed, int(e.success), e.time_to_goal_s or "",
                                round(e.spread_start_m, 3), round(e.spread_end_m, 3),
                                round(e.drive_fraction, 4)])  # fmt: skip
    if episodes is not None:
        episodes.update(eps)
    return rows
