"""Evaluate policies on GroundAir scenarios, including UGV behaviours they were not trained on.

`transfer_table(policies, scenarios, episodes, seed)` → rows of mean metrics per (policy,
scenario). `write_transfer(run, episodes, seed)` adds the transfer table to a finished training
run folder (transfer.md and transfer.csv; `skyherd transfer RUN` on the command line).
"""

from __future__ import annotations

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


TRANSFER_SEED = 200_000  # the transfer episodes' first seed (unseen by every learner)
TRANSFER_COLUMNS = ["policy", "scenario", "all_in_view_frac", "footprint_ratio", "ugv_losses"]


def write_transfer(run: Path, episodes: int = 10, seed: int = TRANSFER_SEED) -> str:
    """The best policy of each learner in `run` and the baselines on the composite scenario and
    every groundsim behaviour: transfer.md and transfer.csv into `run`; returns the table.
    ValueError (one line) if `run` has no policies/ folder."""
    from skyherd.runio.runfolder import CsvWriter, atomic_write_text, markdown_table

    if not (run / "policies").is_dir():
        raise ValueError(f"{run}: no policies/ folder (not a finished training run)")
    pols = best_policies(run) | baseline_factories()
    rows = transfer_table(pols, ("composite",) + GROUNDSIM_SCENARIOS, episodes, seed)
    head = ["policy", "scenario", "all-in-view frac", "footprint/circle", "UGV losses / ep"]
    table = markdown_table(head, rows)
    atomic_write_text(run / "transfer.md", "# Transfer to groundsim UGV behaviours\n\n" + table)
    w = CsvWriter(run / "transfer.csv", TRANSFER_COLUMNS)
    for r in rows:
        w.write(dict(zip(w.columns, r)))
    w.close()
    return table
