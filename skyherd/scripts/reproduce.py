"""`skyherd reproduce sql`: the seed study's whole table in one command (policy/sql/reproduce.py),
each run a Ray task (local Ray on loopback by default, `--ray-address` for a cluster; a local
process pool when Ray is not installed or with `--backend process`). Writes to the run folder:
config.json, metrics.csv (one row per run, with its seed and worker), episodes/<run>.csv,
maps/K<K>_seed<s>.json (each map, in the --env format), results.md (= summary.md), the figures.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from itertools import chain
from pathlib import Path

from skyherd.report import reproduce as report
from skyherd.runio.runfolder import RunFolder
from skyherd.scripts.cli import UsageError, apply_quick, quick_help, usage
from skyherd.scripts.options import add_options, opt

STUDIES = ("sql",)
LEARNERS = ("sql", "sql-d", "sql-sie")
QUICK = {"episodes": 1000, "seeds": 2, "agents": [9]}  # --quick (scripts.cli.apply_quick)


@dataclass(frozen=True)
class ReproduceOptions:
    """The options of `skyherd reproduce sql` (scripts.options: one field, one option)."""

    rules: tuple[str, ...] = opt(("published",), choices=("published", "intended"))
    """rule set(s): published = the public MATLAB code, intended = the paper's text"""
    ties: str | None = opt(None, choices=("first", "random"))
    """greedy tie-breaking (default: first for published, random for intended)"""
    switch: tuple[str, ...] = opt((), action="append", metavar="FIELD=VALUE")
    """set one rule switch of every --rules set (repeatable; fields and values: docs/sql.md,
    policy/sql/params.py Rules), e.g. --switch assign_cell=own"""
    learners: tuple[str, ...] = opt(LEARNERS, choices=LEARNERS)  # learners to run
    seeds: int = 10  # seeds 0..S-1 per config
    agents: tuple[int, ...] = (9, 16)  # K
    sharing_periods: tuple[int, ...] = (1, 20, 50)
    """SQL-SIE sharing periods N; the first is the one compared with SQL"""
    scaling_agents: tuple[int, ...] = opt((), nargs="*")
    """extra K for the scaling figure, all three learners (e.g. 25 36; default none)"""
    roi_table_seed: str = opt("auto", metavar="SEED|auto")
    """seed of the one fixed ROI table per K that the published rules walk (Rules.roi_table
    'fixed'); auto: per K the first seed whose greedy walks all arrive
    (policy.sql.roitable.walkable_seed: a property of the table, found before any run; the
    published code's runs had no walk failure); default auto; 'per-run' tables: --switch
    roi_table=per-run"""
    episodes: int = 10_000  # episodes per run
    max_steps: int = 1000  # step cap per episode
    env: str | None = None
    """a map file (JSON, see docs/sql.md) used for every run; default: a generated map per seed
    (and K)"""
    backend: str = opt("auto", choices=("auto", "ray", "process"))
    """auto: Ray if installed, else a local process pool"""
    ray_address: str | None = None  # join this Ray cluster (default: local, loopback)
    workers: int = 2  # local CPUs to use
    window: int = 100  # moving-average window
    runs_dir: str = "runs"  # where run folders go
    reuse: tuple[str, ...] = opt((), nargs="*", metavar="RUN_FOLDER")
    """earlier reproduce-sql run folders whose finished runs with the same settings are taken
    over instead of run again (e.g. after an interrupted run)"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", choices=STUDIES, help="which study (sql: the SQL-SIE study)")
    add_options(parser, ReproduceOptions)
    parser.add_argument(
        "--quick", action="store_true", help=quick_help("1000 episodes, 2 seeds, K = 9")
    )


def _check(args):
    """The study's runs (policy.sql.reproduce.specs_of) from the options; UsageError."""
    from skyherd.policy.sql.envfile import load_env_file
    from skyherd.policy.sql.reproduce import specs_of

    apply_quick(args, QUICK)
    if args.episodes < 10 or args.max_steps < 1 or args.seeds < 1 or args.workers < 1:
        raise UsageError("need --episodes >= 10, --max-steps >= 1, --seeds >= 1, --workers >= 1")
    env = None if args.env is None else usage(load_env_file, args.env)
    if env is not None:
        args.agents, args.scaling_agents = [len(env.starts)], []
    return usage(specs_of, args, env)


def _reused(args, specs) -> dict:
    """Finished runs of the --reuse folders: {spec: RunResult} for specs with equal settings."""
    found = {}
    for d in map(Path, args.reuse):
        try:
            found |= report.read_finished(d, specs, args.env, found)
        except ValueError as e:
            raise UsageError(f"--reuse {d}: {e}") from None
    return found


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from skyherd.policy.sql.metrics import study_summary
    from skyherd.policy.sql.sweep import run_all
    from skyherd.runio.parallel import chosen_backend

    specs = _check(args)
    backend = usage(chosen_backend, args.backend, args.ray_address)
    reused = _reused(args, specs)
    folder = RunFolder("reproduce-sql", root=args.runs_dir)
    for sub in ("episodes", "maps"):
        (folder.path / sub).mkdir()
    folder.write_config(report.config(args, specs, backend))
    todo = [s for s in specs if s not in reused]
    print(f"run folder: {folder.path}\n{len(todo)} runs on {backend}, {len(reused)} reused")
    table = folder.metrics(report.FIELDS)
    results, summaries = {}, {}
    t0 = time.perf_counter()
    done = run_all(todo, backend, args.workers, args.ray_address) if todo else ()
    with tqdm(total=len(specs), unit="run", desc="reproduce sql", smoothing=0.1) as bar:
        for spec, res in chain(reused.items(), done):
            s = study_summary(res.steps, res.success, args.max_steps, args.window)
            results[spec], summaries[spec] = res, s
            report.write_run(folder, table, spec, res, s)
            bar.set_postfix_str(f"{spec.key} {res.wall_s:.1f}s", refresh=False)
            bar.update(1)
    table.close()
    wall = time.perf_counter() - t0
    md = report.write_results(folder, args, specs, results, summaries, wall, backend, len(reused))
    print(md)
    print(f"wrote {folder.path}")
    return 0
