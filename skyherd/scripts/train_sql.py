"""`skyherd train sql`: the seed's swarm Q-learning experiments (policy/sql/experiments.py),
with plots and a results table."""

from __future__ import annotations

import argparse
import json
from dataclasses import dataclass

from skyherd.policy.sql.experiments import EXPERIMENTS
from skyherd.report import sql as report
from skyherd.runio.runfolder import RunFolder, atomic_write_text
from skyherd.scripts.cli import quick_help, usage
from skyherd.scripts.options import add_options, opt


@dataclass(frozen=True)
class SqlOptions:
    """The options of `skyherd train sql` (scripts.options: one field, one option)."""

    experiment: str = opt("all", choices=(*EXPERIMENTS, "all"))  # which experiment to run
    seeds: tuple[int, ...] = (0, 1, 2)  # learner seeds
    episodes: int | None = None  # training episodes per run (default 10000; --quick: 2000)
    agents: tuple[int, ...] | None = None
    """K values for the compare and sharing experiments (default 9 16)"""
    scalability_agents: tuple[int, ...] | None = None
    """K values for the scalability experiment (default 4 9 16)"""
    share_every: int = 20  # SQL-SIE sharing period N in compare / scalability
    sharing_periods: tuple[int, ...] = (1, 20, 50)  # sharing periods N for the sharing experiment
    max_steps: int = 1000  # step limit per episode
    map_seed: int = 0  # obstacle map seed
    rules: str = opt("intended", choices=("published", "intended"))
    """rule set: published = the public MATLAB code, intended = the paper (default: intended,
    unlike `reproduce sql`: the published ROI walk moves agents through one another, so only the
    intended rules give a flyable plan_K<K>.json)"""
    ties: str | None = opt(None, choices=("first", "random"))
    """greedy tie-breaking (default: first for published, random for intended)"""
    env: str | None = None  # map file (JSON, docs/sql.md) for every run; K comes from the file
    window: int | None = None  # moving-average window of curves and convergence (default 100)
    runs_dir: str = opt("runs", aliases=("--out",))  # where run folders go; --out is the older name


def add_arguments(parser: argparse.ArgumentParser, learner: str = "sql") -> None:
    add_options(parser, SqlOptions)
    parser.add_argument(
        "--quick",
        action="store_true",
        help=quick_help("2000 episodes, K = 4 (and 4, 9 for scalability), window 20"),
    )


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from skyherd.policy.sql import experiments as X

    p = usage(X.ExperimentParams.of, args)
    folder = RunFolder("train-sql", root=args.runs_dir)
    (folder.path / "episodes").mkdir()
    folder.write_config(p.config(args.env, bool(args.quick)))
    if p.env is not None:
        atomic_write_text(folder.file("map.json"), p.env.to_json())
    print(f"run folder: {folder.path}")
    print("hyper-parameters:", p.hyper)
    runs = []
    metrics_csv = folder.metrics(report.COLUMNS)
    total = len(p.configs) * len(p.seeds) * p.hyper.episodes
    with tqdm(total=total, unit="ep", desc="train sql", smoothing=0.05) as bar:
        start = lambda c, seed: bar.set_postfix_str(f"{c.label} seed {seed}")  # noqa: E731
        for r in X.train_all(p, bar.update, start):
            runs.append(r)
            report.write_run(folder, metrics_csv, r, p.hyper.episodes)
    metrics_csv.close()
    table = report.write_results(folder, p, runs)
    plans, refused = X.learned_plans(runs, p.seeds[0])  # for flying them later
    for k, why in refused.items():
        print(f"no plan for K={k} (no plan_K{k}.json): {why}")
    for k, plan in plans.items():
        atomic_write_text(folder.file(f"plan_K{k}.json"), json.dumps(plan) + "\n")
    print(table)
    print(f"wrote {folder.path}")
    return 0
