"""`skyherd reproduce sql`'s report: a run's episodes as CSV, its metrics.csv row, results.md
(the table over seeds) and the figures (learning, success, sharing period, scaling with K); and
the finished runs read back from an earlier run folder (`read_finished`, for --reuse).
matplotlib is imported inside the plot."""

from __future__ import annotations

import csv
import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from skyherd.runio.runfolder import atomic_write_text, markdown_table

FIELDS = ["run", "rules", "algorithm", "n_agents", "share_every", "seed", "worker",
          "wall_s", "tail_metric", "tail_success", "tail_on_target", "convergence",
          "first_all_reached"]  # fmt: skip


def metrics_row(spec, res, s) -> dict:
    """A run's metrics.csv row: its spec (policy.sql.sweep.RunSpec), result and study summary."""
    return {
        "run": spec.key, "rules": spec.rules.name, "algorithm": spec.algorithm,
        "n_agents": spec.n_agents, "share_every": spec.share_every,
        "seed": spec.seed, "worker": res.worker, "wall_s": round(res.wall_s, 3),
        "tail_metric": round(s.tail_metric, 2), "tail_success": s.tail_success,
        "tail_on_target": s.tail_on_target, "convergence": s.convergence or "",
        "first_all_reached": s.first_all_reached or "",
    }  # fmt: skip


def episode_csv(res) -> str:
    cols = [res.steps, res.success.astype(int), res.reached, res.collisions, res.agent_steps]
    rows = np.column_stack([np.arange(1, res.steps.shape[0] + 1), *cols]).tolist()
    lines = ["episode,steps,on_target,reached,collisions,agent_steps"]
    lines += [",".join(map(str, r)) for r in rows]
    return "\n".join(lines) + "\n"


def config(args, specs, backend: str) -> dict:
    """config.json of the study: its options (checked `args`), rule sets, budget and runs."""
    return {
        "study": args.study, "rules": {r: asdict(s.rules) for s in specs for r in [s.rules.name]},
        "hyper": asdict(specs[0].hyper), "roi_pretrain": asdict(specs[0].pretrain),
        "seeds": list(range(args.seeds)), "agents": args.agents,
        "scaling_agents": args.scaling_agents, "sharing_periods": args.sharing_periods,
        "env": args.env, "backend": backend, "ray_address": args.ray_address,
        "workers": args.workers, "window": args.window, "runs": [s.key for s in specs],
        "reused_from": args.reuse,
    }  # fmt: skip


def write_run(folder, table, spec, res, s) -> None:
    """A finished run into run folder `folder`: episodes/<run>.csv, its map (once per K and
    seed) and its row of metrics.csv (`table`); `s` its study summary."""
    atomic_write_text(folder.path / "episodes" / f"{spec.key}.csv", episode_csv(res))
    mp = folder.path / "maps" / f"K{spec.n_agents}_seed{spec.seed}.json"
    if not mp.exists():
        atomic_write_text(mp, res.env.to_json())
    table.write(metrics_row(spec, res, s))


def write_results(folder, args, specs, results, summaries, wall, backend, n_reused) -> str:
    """results.md (= summary.md) with the figures' names, and the figures; returns it."""
    md = results_md(args, specs, results, summaries, wall, backend, n_reused)
    md += "\nFigures: " + ", ".join(figures(folder, args, specs, results)) + "\n"
    folder.write_summary(md)
    atomic_write_text(folder.file("results.md"), md)
    return md


def read_finished(folder: Path, specs: list, env_path: str | None, known=()) -> dict:
    """The finished runs of an earlier reproduce-sql run folder whose settings are those of
    `specs` (policy.sql.sweep.RunSpec; same episodes, step cap and map `env_path`), but for
    those `known` already: {spec: RunResult}. ValueError if the folder is not one, or has
    other settings."""
    from skyherd.policy.sql.envfile import EnvSpec
    from skyherd.policy.sql.sweep import RunResult

    by_key = {s.key: s for s in specs}
    try:
        cfg = json.loads((folder / "config.json").read_text())
        with open(folder / "metrics.csv") as f:
            rows = list(csv.DictReader(f))
    except (OSError, ValueError) as e:
        raise ValueError(f"not a reproduce-sql run folder ({e})") from None
    if cfg.get("hyper") != asdict(specs[0].hyper) or cfg.get("env") != env_path:
        raise ValueError("other episodes/step cap/map settings than this run")
    found = {}
    for row in rows:
        spec = by_key.get(row["run"])
        if (
            spec is None
            or spec in found
            or spec in known
            or cfg["rules"].get(spec.rules.name) != asdict(spec.rules)
        ):
            continue
        path = folder / "episodes" / f"{spec.key}.csv"
        a = np.loadtxt(path, delimiter=",", skiprows=1, dtype=np.int64, ndmin=2)
        env = EnvSpec.load(folder / "maps" / f"K{spec.n_agents}_seed{spec.seed}.json")
        found[spec] = RunResult(a[:, 1], a[:, 2].astype(bool), a[:, 3], a[:, 4], a[:, 5], env,
                                float(row["wall_s"]), row["worker"])  # fmt: skip
    return found


def learner_label(alg: str, n: int) -> str:
    return alg.upper() + (f" N={n}" if alg == "sql-sie" else "")


def groups(specs):
    """(rules, alg, K, N) → list of specs over seeds, in table order."""
    g: dict[tuple, list] = {}
    for s in specs:
        g.setdefault((s.rules.name, s.algorithm, s.n_agents, s.share_every), []).append(s)
    return g


def results_md(args, specs, results, summaries, wall, backend, n_reused=0) -> str:
    from skyherd.policy.sql.metrics import mean_sd

    headers = ["rules", "learner", "K", "metric, last 10 %", "success, last 10 %",
               "all on targets, last 10 %", "converged at episode", "first all reached",
               "episodes/s per run"]  # fmt: skip
    rows = []
    for (rname, alg, K, n), ss in groups(specs).items():
        sm = [summaries[s] for s in ss]
        eps = [args.episodes / results[s].wall_s for s in ss]
        never = sum(x.first_all_reached is None for x in sm)
        rows.append(
            [
                rname, learner_label(alg, n), K,
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


def panel_plot(path, panels, title, ylabel, window, cap, results, what):
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


def figures(folder, args, specs, results) -> list[str]:
    by_group = groups(specs)
    g = lambda key: by_group.get(key, [])  # noqa: E731
    cap, w = args.max_steps, args.window
    n1 = args.sharing_periods[0]
    metric_y = f"min(max steps over agents, {cap}) per episode [steps]"
    names = []
    for rname in dict.fromkeys(s.rules.name for s in specs):
        tag = f"rules {rname}"
        compare = [
            (f"K = {K}", [(learner_label(a, n), g((rname, a, K, n))) for a, n in
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
                panel_plot(folder.file(name), compare, f"SQL vs SQL-D vs SQL-SIE, {tag}",
                            ylabel, w, cap, results, what)  # fmt: skip
                names.append(name)
        sharing = [
            (f"SQL-SIE, K = {K}", [(f"N = {n}", g((rname, "sql-sie", K, n)))
                                   for n in args.sharing_periods])
            for K in args.agents
        ]  # fmt: skip
        sharing, name = _only_run(sharing), f"sharing_{rname}.png"
        if sharing:
            panel_plot(folder.file(name), sharing, f"sharing period N, {tag}", metric_y, w,
                        cap, results, "metric")  # fmt: skip
            names.append(name)
        Ks = [*args.agents, *[k for k in args.scaling_agents if k not in args.agents]]
        if len(Ks) > 1:
            scaling = [
                (learner_label(a, n), [(f"K = {K}", g((rname, a, K, n))) for K in Ks])
                for a, n in (("sql", 0), ("sql-d", 0), ("sql-sie", n1))
            ]
            scaling, name = _only_run(scaling), f"scaling_{rname}.png"
            if scaling:
                panel_plot(folder.file(name), scaling, f"scaling with K, {tag}", metric_y, w,
                            cap, results, "metric")  # fmt: skip
                names.append(name)
    return names
