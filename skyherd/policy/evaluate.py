"""Evaluate policies on GroundAir scenarios, including UGV behaviours they were not trained on.

`transfer_table(policies, scenarios, episodes, seed)` → rows of mean metrics per (policy,
scenario). Run on a finished training run folder to add the transfer table:

    python -m skyherd.policy.evaluate runs/<time>-train-ab [--episodes 10]

(writes transfer.md and transfer.csv into the folder, printing the table).
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

from skyherd.policy.demos import ExpertParams, random_policy, rollout_stats, scripted_expert
from skyherd.task.scenarios import GROUNDSIM_SCENARIOS

Factory = Callable[[int], Callable[[np.ndarray], int]]  # seed → policy


def transfer_table(
    policies: dict[str, Factory],
    scenarios: tuple[str, ...],
    episodes: int,
    seed: int,
    gamma: float = 0.97,
) -> list[list]:
    """[policy, scenario, all-in-view frac, footprint ratio, UGV losses] per pair."""
    rows = []
    for name, make in policies.items():
        for sc in scenarios:
            _, m = rollout_stats(make(seed), sc, episodes, seed, gamma)
            rows.append([name, sc, m["all_in_view_frac"], m["footprint_ratio"], m["ugv_losses"]])
    return rows


def baseline_factories() -> dict[str, Factory]:
    return {
        "expert (ideal)": lambda s: scripted_expert("composite", ExpertParams(), seed=s),
        "random": lambda s: random_policy(seed=s),
    }


def best_policies(run: Path) -> dict[str, Factory]:
    """The best seed's policy of each learner in a training run folder (by eval all-in-view)."""
    from skyherd.policy.dqn import load_policy

    best: dict[str, tuple[float, Path]] = {}
    for f in sorted((run / "policies").glob("*.npz")):
        pol = load_policy(f)
        key, v = pol.meta["learner"], pol.meta["eval"]["all_in_view_frac"]
        if key not in best or v > best[key][0]:
            best[key] = (v, f)
    out: dict[str, Factory] = {}
    for key, (_, f) in best.items():
        pol = load_policy(f)
        out[f"{key} ({f.stem})"] = lambda s, pol=pol: pol
    return out


def main(argv: list[str] | None = None) -> int:
    from skyherd.runio.runfolder import CsvWriter, atomic_write_text, markdown_table

    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("run", type=Path, help="a train-irl/train-ab run folder")
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--seed", type=int, default=200_000)
    args = ap.parse_args(argv)
    if not (args.run / "policies").is_dir():
        print(f"{args.run}: no policies/ folder (not a finished training run)", file=sys.stderr)
        return 2
    pols = best_policies(args.run) | baseline_factories()
    rows = transfer_table(pols, ("composite",) + GROUNDSIM_SCENARIOS, args.episodes, args.seed)
    head = ["policy", "scenario", "all-in-view frac", "footprint/circle", "UGV losses / ep"]
    table = markdown_table(head, rows)
    atomic_write_text(
        args.run / "transfer.md", "# Transfer to groundsim UGV behaviours\n\n" + table
    )
    w = CsvWriter(
        args.run / "transfer.csv",
        ["policy", "scenario", "all_in_view_frac", "footprint_ratio", "ugv_losses"],
    )
    for r in rows:
        w.write(dict(zip(w.columns, r)))
    w.close()
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
