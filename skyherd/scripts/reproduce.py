"""`skyherd reproduce sql`: the seed study's whole table in one command, runs in parallel.

Runs SQL, SQL-D and SQL-SIE (sharing every N of --sharing-periods episodes) at each K of
--agents, for every seed and rule set, each run a Ray task (local Ray on loopback by default,
`--ray-address` for a cluster; a local process pool when Ray is not installed or with
`--backend process`). Writes to the run folder: config.json, runs.csv (one row per run, with
its seed and worker), episodes/<run>.csv (per episode), maps/K<K>_seed<s>.json (each map, in
the --env format), results.md (= summary.md) and the figures.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import asdict

import numpy as np

from skyherd.report import reproduce as report
from skyherd.runio.runfolder import RunFolder, atomic_write_text
from skyherd.scripts.cli import quick_help

STUDIES = ("sql",)
QUICK = {"episodes": 1000, "seeds": 2, "agents": [9]}  # --quick (scripts.cli.apply_quick)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("study", choices=STUDIES, help="which study (sql: the SQL-SIE study)")
    parser.add_argument(
        "--rules", nargs="+", choices=("published", "intended"), default=["published"],
        help="rule set(s): published = the public MATLAB code, intended = the paper's text "
        "(default: published)",
    )  # fmt: skip
    parser.add_argument(
        "--ties", choices=("first", "random"), default=None,
        help="greedy tie-breaking (default: first for published, random for intended)",
    )  # fmt: skip
    parser.add_argument(
        "--switch", action="append", default=[], metavar="FIELD=VALUE",
        help="set one rule switch of every --rules set (repeatable; fields and values: "
        "docs/sql.md, policy/sql/params.py Rules), e.g. --switch assign_cell=own",
    )  # fmt: skip
    parser.add_argument(
        "--learners", nargs="+", choices=("sql", "sql-d", "sql-sie"),
        default=["sql", "sql-d", "sql-sie"], help="learners to run (all three)",
    )  # fmt: skip
    parser.add_argument("--seeds", type=int, default=10, help="seeds 0..S-1 per config (10)")
    parser.add_argument("--agents", type=int, nargs="+", default=[9, 16], help="K (9 16)")
    parser.add_argument(
        "--sharing-periods", type=int, nargs="+", default=[1, 20, 50],
        help="SQL-SIE sharing periods N (1 20 50); the first is the one compared with SQL",
    )  # fmt: skip
    parser.add_argument(
        "--scaling-agents", type=int, nargs="*", default=[],
        help="extra K for the scaling figure, all three learners (e.g. 25 36; default none)",
    )  # fmt: skip
    parser.add_argument(
        "--roi-table-seed", default="auto", metavar="SEED|auto",
        help="seed of the one fixed ROI table per K that the published rules walk "
        "(Rules.roi_table 'fixed'); auto: per K the first seed whose greedy walks all arrive "
        "(policy.sql.roitable.walkable_seed: a property of the table, found before any run; "
        "the published code's runs had no walk failure); default auto; 'per-run' tables: "
        "--switch roi_table=per-run",
    )  # fmt: skip
    parser.add_argument("--episodes", type=int, default=10_000, help="episodes per run (10000)")
    parser.add_argument("--max-steps", type=int, default=1000, help="step cap per episode (1000)")
    parser.add_argument(
        "--env", default=None,
        help="a map file (JSON, see docs/sql.md) used for every run; default: a generated map "
        "per seed (and K)",
    )  # fmt: skip
    parser.add_argument(
        "--backend", choices=("auto", "ray", "process"), default="auto",
        help="auto: Ray if installed, else a local process pool (default auto)",
    )  # fmt: skip
    parser.add_argument(
        "--ray-address", default=None, help="join this Ray cluster (default: local, loopback)"
    )
    parser.add_argument("--workers", type=int, default=2, help="local CPUs to use (2)")
    parser.add_argument("--window", type=int, default=100, help="moving-average window (100)")
    parser.add_argument(
        "--quick", action="store_true", help=quick_help("1000 episodes, 2 seeds, K = 9")
    )
    parser.add_argument("--runs-dir", default="runs", help="where run folders go (runs)")
    parser.add_argument(
        "--reuse", nargs="*", default=[], metavar="RUN_FOLDER",
        help="earlier reproduce-sql run folders whose finished runs with the same settings are "
        "taken over instead of run again (e.g. after an interrupted run)",
    )  # fmt: skip


def _specs(args, env):
    from dataclasses import replace

    from skyherd.policy.sql.params import Rules, SQLHyper
    from skyherd.policy.sql.sweep import RunSpec

    hyper = SQLHyper(episodes=args.episodes, max_steps=args.max_steps)
    Ns = args.sharing_periods
    specs = []
    for rname in args.rules:
        named = Rules.named(rname, args.ties, args.switches)
        for K in dict.fromkeys([*args.agents, *args.scaling_agents]):
            rules, pre = named, _table(args, named, hyper, K, env)
            if pre.seed and rules.roi_phase == "pretrained" and rules.roi_table == "fixed":
                rules = replace(rules, name=f"{rules.name}-table{pre.seed}")  # its label in tables
            cfgs = [("sql", 0), ("sql-d", 0)]
            cfgs += [("sql-sie", n) for n in (Ns if K in args.agents else Ns[:1])]
            for alg, n in (c for c in cfgs if c[0] in args.learners):
                for seed in range(args.seeds):
                    specs.append(RunSpec(alg, K, n, seed, rules, hyper, pre, env=env))
    return specs


def _table(args, rules, hyper, K: int, env):
    """The ROI table's pre-training settings of formation K: --roi-table-seed, or with auto the
    first walkable table seed of its layout (the map given, else the generated one)."""
    from skyherd.policy.sql.envfile import generate_env
    from skyherd.policy.sql.params import RoiPretrain
    from skyherd.policy.sql.roitable import walkable_seed

    if args.roi_table_seed != "auto":
        return RoiPretrain(seed=args.roi_table_seed)
    if rules.roi_phase != "pretrained" or rules.roi_table != "fixed":
        return RoiPretrain()  # no fixed table is walked: nothing to choose
    layout = (env if env is not None else generate_env(K, 0)).layout()
    seed, holes = walkable_seed(layout, hyper, rules, RoiPretrain())
    print(f"K = {K}: ROI table seed {seed} ({holes} walk holes; --roi-table-seed auto)")
    return RoiPretrain(seed=seed)


def _check(args):
    from skyherd.scripts.cli import UsageError, apply_quick

    apply_quick(args, QUICK)
    if args.episodes < 10 or args.max_steps < 1 or args.seeds < 1 or args.workers < 1:
        raise UsageError("need --episodes >= 10, --max-steps >= 1, --seeds >= 1, --workers >= 1")
    if args.roi_table_seed != "auto":
        try:
            args.roi_table_seed = int(args.roi_table_seed)
        except ValueError:
            args.roi_table_seed = -1
        if args.roi_table_seed < 0:
            raise UsageError("--roi-table-seed must be auto or an integer >= 0")
    from skyherd.policy.sql.params import Rules

    args.switches = {}
    for sw in args.switch:
        field, eq, value = sw.partition("=")
        if not eq:
            raise UsageError(f"--switch {sw}: expected FIELD=VALUE, e.g. assign_cell=own")
        args.switches[field.strip()] = value.strip()
    try:
        for rname in args.rules:
            Rules.named(rname, args.ties, args.switches)
    except ValueError as e:
        raise UsageError(f"--switch: {e}") from None
    if min(args.sharing_periods) < 1:
        raise UsageError("sharing periods must be >= 1 (SQL-D is the no-sharing learner)")
    if args.window < 1 or args.window > args.episodes:
        raise UsageError("--window must be in 1..episodes")
    env = None
    if args.env is not None:
        from skyherd.policy.sql.envfile import EnvSpec

        try:
            env = EnvSpec.load(args.env)
            env.layout()
        except (OSError, ValueError) as e:
            raise UsageError(f"--env {args.env}: {e}") from None
        args.agents, args.scaling_agents = [len(env.starts)], []
    else:
        from skyherd.policy.sql.layout import formation

        for K in (*args.agents, *args.scaling_agents):
            try:
                formation(K)
            except ValueError as e:
                raise UsageError(str(e)) from None
    if args.backend == "ray" or args.ray_address:
        from skyherd.policy.sql.sweep import ray_available

        if not ray_available():
            raise UsageError("Ray is not installed: pip install -e '.[ray]' (or --backend process)")
    return env


def _reused(args, specs) -> dict:
    """Finished runs of the --reuse folders: {spec: RunResult} for specs with equal settings."""
    import csv
    import json
    from pathlib import Path

    from skyherd.policy.sql.envfile import EnvSpec
    from skyherd.policy.sql.sweep import RunResult
    from skyherd.scripts.cli import UsageError

    by_key = {s.key: s for s in specs}
    found = {}
    for d in map(Path, args.reuse):
        try:
            cfg = json.loads((d / "config.json").read_text())
            rows = list(csv.DictReader(open(d / "metrics.csv")))
        except (OSError, ValueError) as e:
            raise UsageError(f"--reuse {d}: not a reproduce-sql run folder ({e})") from None
        if cfg.get("hyper") != asdict(specs[0].hyper) or cfg.get("env") != args.env:
            raise UsageError(f"--reuse {d}: other episodes/step cap/map settings than this run")
        for row in rows:
            spec = by_key.get(row["run"])
            if (
                spec is None
                or spec in found
                or cfg["rules"].get(spec.rules.name) != asdict(spec.rules)
            ):
                continue
            a = np.loadtxt(
                d / "episodes" / f"{spec.key}.csv",
                delimiter=",",
                skiprows=1,
                dtype=np.int64,
                ndmin=2,
            )
            env = EnvSpec.load(d / "maps" / f"K{spec.n_agents}_seed{spec.seed}.json")
            found[spec] = RunResult(a[:, 1], a[:, 2].astype(bool), a[:, 3], a[:, 4], a[:, 5], env,
                                    float(row["wall_s"]), row["worker"])  # fmt: skip
    return found


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from skyherd.policy.sql.metrics import study_summary
    from skyherd.policy.sql.sweep import ray_available, run_all

    env = _check(args)
    specs = _specs(args, env)
    backend = args.backend
    if backend == "auto":
        backend = "ray" if ray_available() else "process"
        if backend == "process":
            print("Ray is not installed: running on a local process pool (pip install -e '.[ray]')")
    reused = _reused(args, specs)
    folder = RunFolder("reproduce-sql", root=args.runs_dir)
    for sub in ("episodes", "maps"):
        (folder.path / sub).mkdir()
    folder.write_config(
        {
            "study": args.study,
            "rules": {r: asdict(s.rules) for s in specs for r in [s.rules.name]},
            "hyper": asdict(specs[0].hyper),
            "roi_pretrain": asdict(specs[0].pretrain),
            "seeds": list(range(args.seeds)),
            "agents": args.agents,
            "scaling_agents": args.scaling_agents,
            "sharing_periods": args.sharing_periods,
            "env": args.env,
            "backend": backend,
            "ray_address": args.ray_address,
            "workers": args.workers,
            "window": args.window,
            "runs": [s.key for s in specs],
            "reused_from": args.reuse,
        }
    )
    todo = [s for s in specs if s not in reused]
    print(f"run folder: {folder.path}\n{len(todo)} runs on {backend}, {len(reused)} reused")
    table = folder.metrics(report.FIELDS)
    results, summaries = {}, {}
    t0 = time.perf_counter()

    def finished():
        yield from reused.items()
        if todo:
            yield from run_all(todo, backend, args.workers, args.ray_address)

    with tqdm(total=len(specs), unit="run", desc="reproduce sql", smoothing=0.1) as bar:
        for spec, res in finished():
            s = study_summary(res.steps, res.success, args.max_steps, args.window)
            results[spec], summaries[spec] = res, s
            atomic_write_text(folder.path / "episodes" / f"{spec.key}.csv", report.episode_csv(res))
            mp = folder.path / "maps" / f"K{spec.n_agents}_seed{spec.seed}.json"
            if not mp.exists():
                atomic_write_text(mp, res.env.to_json())
            table.write(report.metrics_row(spec, res, s))
            bar.set_postfix_str(f"{spec.key} {res.wall_s:.1f}s", refresh=False)
            bar.update(1)
    table.close()
    wall = time.perf_counter() - t0
    md = report.results_md(args, specs, results, summaries, wall, backend, len(reused))
    figs = report.figures(folder, args, specs, results)
    md += "\nFigures: " + ", ".join(figs) + "\n"
    folder.write_summary(md)
    atomic_write_text(folder.file("results.md"), md)
    print(md)
    print(f"wrote {folder.path}")
    return 0
