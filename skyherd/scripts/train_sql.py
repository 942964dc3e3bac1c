"""`skyherd train sql`: the seed's swarm Q-learning experiments, with plots and a results table.

Experiments (each over every seed):
- compare:     SQL vs SQL-D vs SQL-SIE at each K of --agents (default 9 and 16);
- sharing:     SQL-SIE with knowledge sharing every N of --sharing-periods (1, 20, 50) episodes;
- scalability: all three learners at K = 4, 9, 16.
Identical configurations are trained once and reused across experiments.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict, dataclass, replace

from skyherd.report import sql as report
from skyherd.runio.runfolder import RunFolder, atomic_write_text
from skyherd.scripts.cli import quick_help

EXPERIMENTS = ("compare", "sharing", "scalability")


@dataclass(frozen=True)
class Config:
    """One trained configuration (run once per seed)."""

    algorithm: str
    n_agents: int
    share_every: int

    @property
    def label(self) -> str:
        n = f" N={self.share_every}" if self.algorithm == "sql-sie" else ""
        return f"{self.algorithm.upper()} K={self.n_agents}{n}"

    @property
    def key(self) -> str:
        return f"{self.algorithm}_K{self.n_agents}_N{self.share_every}"


def add_arguments(parser: argparse.ArgumentParser, learner: str = "sql") -> None:
    parser.add_argument(
        "--experiment",
        choices=(*EXPERIMENTS, "all"),
        default="all",
        help="which experiment to run (default: all)",
    )
    parser.add_argument(
        "--seeds", type=int, nargs="+", default=[0, 1, 2], help="learner seeds (default: 0 1 2)"
    )
    parser.add_argument(
        "--episodes",
        type=int,
        default=None,
        help="training episodes per run (default 10000; --quick: 2000)",
    )
    parser.add_argument(
        "--agents",
        type=int,
        nargs="+",
        default=None,
        help="K values for the compare and sharing experiments (default 9 16)",
    )
    parser.add_argument(
        "--scalability-agents",
        type=int,
        nargs="+",
        default=None,
        help="K values for the scalability experiment (default 4 9 16)",
    )
    parser.add_argument(
        "--share-every",
        type=int,
        default=20,
        help="SQL-SIE sharing period N in compare / scalability (default 20)",
    )
    parser.add_argument(
        "--sharing-periods",
        type=int,
        nargs="+",
        default=[1, 20, 50],
        help="sharing periods N for the sharing experiment (default 1 20 50)",
    )
    parser.add_argument("--max-steps", type=int, default=1000, help="step limit per episode")
    parser.add_argument("--map-seed", type=int, default=0, help="obstacle map seed (default 0)")
    parser.add_argument(
        "--rules", choices=("published", "intended"), default="intended",
        help="rule set: published = the public MATLAB code, intended = the paper (default: "
        "intended, unlike `reproduce sql`: the published ROI walk moves agents through one "
        "another, so only the intended rules give a flyable plan_K<K>.json)",
    )  # fmt: skip
    parser.add_argument(
        "--ties", choices=("first", "random"), default=None,
        help="greedy tie-breaking (default: first for published, random for intended)",
    )  # fmt: skip
    parser.add_argument(
        "--env", default=None,
        help="map file (JSON, docs/sql.md) for every run; K comes from the file",
    )  # fmt: skip
    parser.add_argument(
        "--window",
        type=int,
        default=None,
        help="moving-average window of curves and convergence (default 100)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help=quick_help("2000 episodes, K = 4 (and 4, 9 for scalability), window 20"),
    )
    parser.add_argument(
        "--runs-dir", "--out", dest="runs_dir", default="runs",
        help="where run folders go (runs); --out is the older name",
    )  # fmt: skip


def _plan(args: argparse.Namespace) -> tuple[dict[str, list[Config]], dict]:
    from skyherd.policy.sql.layout import STARTS

    q = args.quick
    agents = args.agents or ([4] if q else [9, 16])
    scal = args.scalability_agents or ([4, 9] if q else [4, 9, 16])
    if args.env is not None:
        agents = scal = [len(_env(args).starts)]
    for k in (*agents, *scal):
        if k not in STARTS and args.env is None:
            from skyherd.scripts.cli import UsageError

            raise UsageError(f"K={k} has no built-in layout; use K in {sorted(STARTS)}")
    N = args.share_every
    exps = EXPERIMENTS if args.experiment == "all" else (args.experiment,)
    algs = ("sql", "sql-d", "sql-sie")
    cfg = lambda a, k, n=N: Config(a, k, n if a == "sql-sie" else 0)  # noqa: E731
    plan: dict[str, list[Config]] = {}
    if "compare" in exps:
        plan["compare"] = [cfg(a, k) for k in agents for a in algs]
    if "sharing" in exps:
        plan["sharing"] = [cfg("sql-sie", k, n) for k in agents for n in args.sharing_periods]
    if "scalability" in exps:
        plan["scalability"] = [cfg(a, k) for a in algs for k in scal]
    return plan, {"agents": agents, "scalability_agents": scal}


def _env(args: argparse.Namespace):
    """The --env map (a UsageError if it cannot be read)."""
    from skyherd.policy.sql.envfile import EnvSpec
    from skyherd.scripts.cli import UsageError

    try:
        spec = EnvSpec.load(args.env)
        spec.layout()
    except (OSError, ValueError) as e:
        raise UsageError(f"--env {args.env}: {e}") from None
    return spec


def _check(args: argparse.Namespace) -> None:
    from skyherd.scripts.cli import UsageError

    if args.episodes is not None and args.episodes < 1:
        raise UsageError("--episodes must be >= 1")
    if args.max_steps < 1:
        raise UsageError("--max-steps must be >= 1")
    if args.share_every < 1 or min(args.sharing_periods) < 1:
        raise UsageError("sharing periods must be >= 1 (SQL-D is the no-sharing learner)")
    if len(set(args.seeds)) != len(args.seeds) or min(args.seeds) < 0:
        raise UsageError("--seeds must be distinct non-negative integers")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from skyherd.policy.sql import Algorithm, GridParams, SQLHyper, build_layout, plan_paths, train
    from skyherd.policy.sql.metrics import summarize

    _check(args)
    episodes = args.episodes or (2000 if args.quick else 10_000)
    window = args.window or (20 if args.quick else 100)
    window = min(window, episodes)
    tail = min(500, max(1, episodes // 5))
    plan, sets = _plan(args)
    hyper0 = SQLHyper(episodes=episodes, max_steps=args.max_steps, share_every=args.share_every)
    configs = list(dict.fromkeys(c for cs in plan.values() for c in cs))
    from skyherd.policy.sql.params import Rules

    rules = Rules.named(args.rules, args.ties)
    if args.env is not None:
        spec = _env(args)
        layouts = {len(spec.starts): spec.layout()}
    else:
        layouts = {
            k: build_layout(GridParams(n_agents=k, map_seed=args.map_seed))
            for k in sorted({c.n_agents for c in configs})
        }

    folder = RunFolder("train-sql", root=args.runs_dir)
    (folder.path / "episodes").mkdir()
    config = {
        "experiments": {e: [asdict(c) for c in cs] for e, cs in plan.items()},
        "seeds": list(args.seeds),
        "hyper": asdict(hyper0),
        "grid": {k: asdict(GridParams(n_agents=k, map_seed=args.map_seed)) for k in layouts},
        "rules": asdict(rules),
        "env": args.env,
        "window": window,
        "tail": tail,
        "quick": bool(args.quick),
        **sets,
    }
    folder.write_config(config)
    if args.env is not None:
        atomic_write_text(folder.file("map.json"), spec.to_json())
    print(f"run folder: {folder.path}")
    print("hyper-parameters:", hyper0)

    results: dict[tuple[Config, int], object] = {}
    summaries: dict[tuple[Config, int], object] = {}
    timing: dict[Config, float] = {}
    metrics_csv = folder.metrics(report.COLUMNS)
    total = len(configs) * len(args.seeds) * episodes
    with tqdm(total=total, unit="ep", desc="train sql", smoothing=0.05) as bar:
        for c in configs:
            hyper = replace(hyper0, share_every=max(c.share_every, 1))
            for seed in args.seeds:
                bar.set_postfix_str(f"{c.label} seed {seed}")
                t0 = time.perf_counter()
                r = train(
                    Algorithm(c.algorithm), layouts[c.n_agents], hyper, seed, bar.update, rules
                )
                wall = time.perf_counter() - t0
                timing[c] = timing.get(c, 0.0) + wall
                s = summarize(r.metrics, window, tail)
                results[(c, seed)], summaries[(c, seed)] = r, s
                atomic_write_text(folder.path / "episodes" / f"{c.key}_seed{seed}.csv",
                                  report.episodes_csv(r.metrics, episodes))  # fmt: skip
                metrics_csv.write(report.metrics_row(c, seed, episodes, s, wall))
    metrics_csv.close()

    table, curves = report.results(plan, args.seeds, summaries, results, timing)
    for exp, cs in curves.items():
        report.plot_curves(folder.file(f"curves_{exp}.png"), f"{exp}", cs, window, args.max_steps)

    # The learned SQL-SIE formation plans (seed = first seed), for flying them later.
    # One try per K (its first SQL-SIE run): a K said to have no plan gets no plan file.
    plans, tried = {}, set()
    for (c, seed), r in results.items():
        if c.algorithm == "sql-sie" and seed == args.seeds[0] and c.n_agents not in tried:
            tried.add(c.n_agents)
            try:
                plans[c.n_agents] = plan_paths(r, c.n_agents)
            except ValueError as e:
                print(f"no plan for K={c.n_agents} (no plan_K{c.n_agents}.json): {e}")
    for k, p in plans.items():
        atomic_write_text(folder.file(f"plan_K{k}.json"), json.dumps(p) + "\n")

    summary = report.summary_md(args.seeds, episodes, args.map_seed, tail, window, table, plan)
    folder.write_summary(summary)
    atomic_write_text(folder.file("results.md"), summary)
    print(table)
    print(f"wrote {folder.path}")
    return 0
