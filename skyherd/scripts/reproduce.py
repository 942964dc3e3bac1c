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

from skyherd.runio.runfolder import RunFolder, atomic_write_text, markdown_table
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


def _episode_csv(res) -> str:
    cols = [res.steps, res.success.astype(int), res.reached, res.collisions, res.agent_steps]
    rows = np.column_stack([np.arange(1, res.steps.shape[0] + 1), *cols]).tolist()
    lines = ["episode,steps,on_target,reached,collisions,agent_steps"]
    lines += [",".join(map(str, r)) for r in rows]
    return "\n".join(lines) + "\n"


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
    fields = ["run", "rules", "algorithm", "n_agents", "share_every", "seed", "worker",
              "wall_s", "tail_metric", "tail_success", "tail_on_target", "convergence",
              "first_all_reached"]  # fmt: skip
    table = folder.metrics(fields)
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
            atomic_write_text(folder.path / "episodes" / f"{spec.key}.csv", _episode_csv(res))
            mp = folder.path / "maps" / f"K{spec.n_agents}_seed{spec.seed}.json"
            if not mp.exists():
                atomic_write_text(mp, res.env.to_json())
            table.write(
                {
                    "run": spec.key, "rules": spec.rules.name, "algorithm": spec.algorithm,
                    "n_agents": spec.n_agents, "share_every": spec.share_every,
                    "seed": spec.seed, "worker": res.worker, "wall_s": round(res.wall_s, 3),
                    "tail_metric": round(s.tail_metric, 2), "tail_success": s.tail_success,
                    "tail_on_target": s.tail_on_target, "convergence": s.convergence or "",
                    "first_all_reached": s.first_all_reached or "",
                }
            )  # fmt: skip
            bar.set_postfix_str(f"{spec.key} {res.wall_s:.1f}s", refresh=False)
            bar.update(1)
    table.close()
    wall = time.perf_counter() - t0
    md = _results_md(args, specs, results, summaries, wall, backend, len(reused))
    figs = _figures(folder, args, specs, results)
    md += "\nFigures: " + ", ".join(figs) + "\n"
    folder.write_summary(md)
    atomic_write_text(folder.file("results.md"), md)
    print(md)
    print(f"wrote {folder.path}")
    return 0


def _label(alg: str, n: int) -> str:
    return alg.upper() + (f" N={n}" if alg == "sql-sie" else "")


def _groups(specs):
    """(rules, alg, K, N) → list of specs over seeds, in table order."""
    g: dict[tuple, list] = {}
    for s in specs:
        g.setdefault((s.rules.name, s.algorithm, s.n_agents, s.share_every), []).append(s)
    return g


def _results_md(args, specs, results, summaries, wall, backend, n_reused=0) -> str:
    from skyherd.policy.sql.metrics import mean_sd

    headers = ["rules", "learner", "K", "metric, last 10 %", "success, last 10 %",
               "all on targets, last 10 %", "converged at episode", "first all reached",
               "episodes/s per run"]  # fmt: skip
    rows = []
    for (rname, alg, K, n), ss in _groups(specs).items():
        sm = [summaries[s] for s in ss]
        eps = [args.episodes / results[s].wall_s for s in ss]
        never = sum(x.first_all_reached is None for x in sm)
        rows.append(
            [
                rname, _label(alg, n), K,
                mean_sd([x.tail_metric for x in sm]),
                mean_sd([x.tail_success for x in sm], 2),
                mean_sd([x.tail_on_target for x in sm], 2),
                mean_sd([x.convergence for x in sm], 0)
                + f" ({sum(x.convergence is not None for x in sm)}/{len(sm)})",
                mean_sd([x.first_all_reached for x in sm], 0) + (f" ({never} never)" if never else ""),
                f"{np.mean(eps):,.0f}",
            ]
        )  # fmt: skip
    env = f"map file {args.env}" if args.env else "a generated map per seed and K"
    return (
        f"# skyherd reproduce sql\n\n{args.seeds} seeds (0..{args.seeds - 1}) per row, "
        f"{args.episodes} episodes per run, {env}; {len(specs)} runs on {backend} with "
        f"{args.workers} workers in {wall:.0f} s wall time"
        + (f" ({n_reused} of them taken over from --reuse folders)" if n_reused else "")
        + ".\n\n"
        f"Per-episode metric = min(max over agents of steps, {args.max_steps}). Per run: "
        f"mean over the last 10 % of episodes; success = metric < {args.max_steps} (what the "
        f"published step logs show); all on targets = every agent on its own target; "
        f"converged = first episode after which the {args.window}-episode moving average "
        f"stays below 2× its final value, over the runs (k/n) whose success is >= 0.9. "
        f"Mean ± sd over seeds (population sd).\n\n" + markdown_table(headers, rows)
    )


def _curves(results, ss, window, cap, what):
    from skyherd.policy.sql.metrics import moving_average, study_metric

    if what == "metric":
        series = [study_metric(results[s].steps, cap) for s in ss]
    else:
        series = [(study_metric(results[s].steps, cap) < cap).astype(float) for s in ss]
    ma = np.stack([moving_average(x, window) for x in series])
    return np.arange(window, window + ma.shape[1]), ma.mean(axis=0), ma.std(axis=0)


def _panel_plot(path, panels, title, ylabel, window, cap, results, what):
    """panels: list of (panel title, [(label, specs)]); one subplot each, shared y."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(panels)
    fig, axes = plt.subplots(1, n, figsize=(max(7.0, 5.2 * n), 5.0), sharey=True, squeeze=False)
    axes = axes[0]
    for ax, (ptitle, lines) in zip(axes, panels):
        for label, ss in lines:
            x, mean, sd = _curves(results, ss, window, cap, what)
            n_s = len(ss)
            (ln,) = ax.plot(x, mean, lw=1.3, label=f"{label} ({n_s} seed{'s' if n_s != 1 else ''})")
            if n_s < 2:  # one seed has no spread: no band
                continue
            lo = np.maximum(mean - sd, 1.0) if what == "metric" else np.clip(mean - sd, 0, 1)
            hi = np.minimum(mean + sd, cap) if what == "metric" else np.clip(mean + sd, 0, 1)
            ax.fill_between(x, lo, hi, color=ln.get_color(), alpha=0.18, lw=0)
        if what == "metric":
            ax.set_yscale("log")
            ax.set_ylim(60, cap * 1.25)
        else:
            ax.set_ylim(-0.02, 1.02)
        ax.set_title(ptitle, fontsize=10)
        ax.set_xlabel("episode")
        ax.grid(True, which="both", alpha=0.3)
        # below the axes: a legend never hides a curve
        ax.legend(
            fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=min(3, len(lines))
        )
    axes[0].set_ylabel(ylabel)
    fig.suptitle(
        f"{title}\nline: mean over seeds of the {window}-episode moving average; band: ± 1 sd "
        "over seeds",
        fontsize=10,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _only_run(panels):
    """The panels' lines that have runs (--learners may leave some out); empty panels dropped."""
    kept = [(t, [(label, ss) for label, ss in lines if ss]) for t, lines in panels]
    return [(t, lines) for t, lines in kept if lines]


def _figures(folder, args, specs, results) -> list[str]:
    groups = _groups(specs)
    g = lambda key: groups.get(key, [])  # noqa: E731
    cap, w = args.max_steps, args.window
    n1 = args.sharing_periods[0]
    metric_y = f"min(max steps over agents, {cap}) per episode [steps]"
    names = []
    for rname in dict.fromkeys(s.rules.name for s in specs):
        tag = f"rules {rname}"
        compare = [
            (f"K = {K}", [(_label(a, n), g((rname, a, K, n))) for a, n in
                          (("sql", 0), ("sql-d", 0), ("sql-sie", n1))])
            for K in args.agents
        ]  # fmt: skip
        compare = _only_run(compare)
        for what, ylabel, name in (
            ("metric", metric_y, f"learning_{rname}.png"),
            (
                "success",
                f"success rate (share of episodes with metric < {cap})",
                f"success_{rname}.png",
            ),
        ):
            if compare:
                _panel_plot(folder.file(name), compare, f"SQL vs SQL-D vs SQL-SIE, {tag}",
                            ylabel, w, cap, results, what)  # fmt: skip
                names.append(name)
        sharing = [
            (f"SQL-SIE, K = {K}", [(f"N = {n}", g((rname, "sql-sie", K, n)))
                                   for n in args.sharing_periods])
            for K in args.agents
        ]  # fmt: skip
        sharing, name = _only_run(sharing), f"sharing_{rname}.png"
        if sharing:
            _panel_plot(folder.file(name), sharing, f"sharing period N, {tag}", metric_y, w,
                        cap, results, "metric")  # fmt: skip
            names.append(name)
        Ks = [*args.agents, *[k for k in args.scaling_agents if k not in args.agents]]
        if len(Ks) > 1:
            scaling = [
                (_label(a, n), [(f"K = {K}", g((rname, a, K, n))) for K in Ks])
                for a, n in (("sql", 0), ("sql-d", 0), ("sql-sie", n1))
            ]
            scaling, name = _only_run(scaling), f"scaling_{rname}.png"
            if scaling:
                _panel_plot(folder.file(name), scaling, f"scaling with K, {tag}", metric_y, w,
                            cap, results, "metric")  # fmt: skip
                names.append(name)
    return names
