"""`python -m skyherd.policy.shepherd.study`: the learned selector against Strömbom's hand-written
shepherd on the same seeds (0 .. N−1; the learned selector was fitted on seeds 1000+).

Prints, per selector: success rate (the flock's centre inside the goal region within the time
limit) with its 95 % Clopper–Pearson interval, median and 90th-percentile time to goal over the
successes, the mean spread at the end, and how often the two chose alike; writes table.md,
episodes.csv and shepherd_study.png (fraction of episodes at the goal against time, and one
seed's tracks) into --out.
"""

from __future__ import annotations

import argparse
import csv
import sys
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
        selector_file: str | None = None, flock: FlockParams | None = None) -> dict:  # fmt: skip
    """Both selectors on seeds first_seed .. first_seed+seeds−1; returns {name: summary}."""
    flock, task = flock if flock is not None else FlockParams(), ShepherdParams()
    sels = {"strombom": StrombomSelector(), "learned": make_selector("learned", selector_file)}
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
        plot(eps, task, flock, out / "shepherd_study.png", first_seed, sels)
    return rows


def plot(eps, task, flock, path: Path, seed: int, sels) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.6))
    t = np.linspace(0, task.limit_s, 401)
    for name, es in eps.items():
        times = np.array([e.time_to_goal_s if e.success else np.inf for e in es])
        a.plot(t, [(times <= x).mean() for x in t], label=name)
    a.set_xlabel("time [s]")
    a.set_ylabel("fraction of episodes with the flock at the goal")
    a.grid(alpha=0.3)
    a.legend()
    for name, sel in sels.items():
        ep = run_episode(seed, sel, flock, task, keep_track=True)
        tr = np.array(ep.track)
        b.plot(tr[:, 2], tr[:, 1], lw=0.8, label=f"{name}: shepherd")
        b.plot(tr[:, 4], tr[:, 3], lw=1.6, label=f"{name}: flock centre")
    g = plt.Circle(task.goal_ne[::-1], task.goal_radius_m, color="g", alpha=0.2, label="goal")
    b.add_patch(g)
    b.set_xlabel("east [m]")
    b.set_ylabel("north [m]")
    b.set_aspect("equal")
    b.set_title(f"seed {seed}")
    b.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m skyherd.policy.shepherd.study", description=__doc__,
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # fmt: skip
    ap.add_argument("--seeds", type=int, default=100, help="episodes per selector")
    ap.add_argument("--first-seed", type=int, default=0, help="first seed")
    ap.add_argument(
        "--out", default="runs/shepherd_study", help="folder for table.md, episodes.csv, the plot"
    )
    ap.add_argument(
        "--selector-file",
        default=None,
        help="the learned selector (default: the kept selector.json)",
    )
    ap.add_argument(
        "--agents",
        type=int,
        default=FlockParams().n,
        help="flock size N (the learned selector was fitted on N = 10 only)",
    )
    ap.add_argument(
        "--neighbours",
        type=int,
        default=None,
        help="agents in each one's local centre of mass (default: FlockParams' 6 for N = 10, "
        "N - 1 for other N: 6 lets a larger flock split)",
    )
    a = ap.parse_args(argv)
    if a.seeds < 1 or a.agents < 2:
        print("--seeds must be >= 1 and --agents >= 2", file=sys.stderr)
        return 2
    d = FlockParams()
    nb = (
        a.neighbours
        if a.neighbours is not None
        else (d.neighbours if a.agents == d.n else a.agents - 1)
    )
    try:
        flock = FlockParams(n=a.agents, neighbours=nb)
        rows = run(a.seeds, a.first_seed, a.out, a.selector_file, flock)
    except ValueError as e:
        print(str(e), file=sys.stderr)
        return 2
    print(f"flock: N = {flock.n}, {flock.neighbours} neighbours")
    print(table(rows))
    print(f"written: {a.out}/table.md, episodes.csv, shepherd_study.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
