"""`skyherd train sql`'s report: its metrics.csv rows, the episodes of a run as CSV, the
results table, the learning curves and summary.md (results.md). matplotlib is imported inside
the plot."""

from __future__ import annotations

import numpy as np

from skyherd.runio.runfolder import atomic_write_text, markdown_table

COLUMNS = [
    "config",
    "algorithm",
    "n_agents",
    "share_every",
    "seed",
    "episodes",
    "episodes_to_converge",
    "final_steps",
    "final_success",
    "first_success",
    "wall_s",
]  # metrics.csv: one row per (configuration, seed)


def metrics_row(r, episodes: int) -> dict:
    """The metrics.csv row of one finished run `r` (policy.sql.experiments.Trained)."""
    c, s = r.config, r.summary
    return {
        "config": c.key,
        "algorithm": c.algorithm,
        "n_agents": c.n_agents,
        "share_every": c.share_every,
        "seed": r.seed,
        "episodes": episodes,
        "episodes_to_converge": s.episodes_to_converge
        if s.episodes_to_converge is not None
        else "",
        "final_steps": s.final_steps,
        "final_success": s.final_success,
        "first_success": s.first_success if s.first_success is not None else "",
        "wall_s": round(r.wall_s, 3),
    }


def write_run(folder, table, r, episodes: int) -> None:
    """A finished run `r` into run folder `folder`: episodes/<config>_seed<s>.csv and its row
    of metrics.csv (`table`)."""
    atomic_write_text(folder.path / "episodes" / f"{r.config.key}_seed{r.seed}.csv",
                      episodes_csv(r.result.metrics, episodes))  # fmt: skip
    table.write(metrics_row(r, episodes))


def write_results(folder, p, runs: list) -> str:
    """The results table, the learning curves (curves_<experiment>.png), summary.md and
    results.md of experiment `p` (policy.sql.experiments.ExperimentParams); returns the table."""
    table, curves = results(p.plan, p.seeds, runs)
    for exp, cs in curves.items():
        plot_curves(folder.file(f"curves_{exp}.png"), f"{exp}", cs, p.window, p.hyper.max_steps)
    summary = summary_md(p.seeds, p.hyper.episodes, p.map_seed, p.tail, p.window, table, p.plan)
    folder.write_summary(summary)
    atomic_write_text(folder.file("results.md"), summary)
    return table


def episodes_csv(m, episodes: int) -> str:
    """A run's episodes (policy.sql metrics `m`) as CSV text, one row per episode."""
    ep = np.column_stack(
        [
            np.arange(1, episodes + 1),
            m.steps,
            m.success.astype(int),
            m.reached,
            m.collisions,
            m.agent_steps,
        ]
    )
    lines = ["episode,steps,success,reached,collisions,agent_steps"]
    lines += [",".join(map(str, row)) for row in ep.tolist()]
    return "\n".join(lines) + "\n"


def fmt_pm(values: list[float], digits: int = 1) -> str:
    if not values:
        return "–"
    a = np.asarray(values, dtype=np.float64)
    return f"{a.mean():.{digits}f} ± {a.std():.{digits}f}"


def first_success(summaries) -> str:
    firsts = [s.first_success for s in summaries if s.first_success is not None]
    never = len(summaries) - len(firsts)
    return fmt_pm(firsts, 0) + (f" ({never} never)" if never else "")


def results(plan: dict, seeds, runs: list):
    """The results table (one row per experiment and configuration) and each experiment's
    learning curves, (label, per-seed steps) pairs, for `plot_curves`; `runs`: the finished
    runs (policy.sql.experiments.Trained)."""
    by_run = {(r.config, r.seed): r for r in runs}
    timing: dict = {}
    for r in runs:
        timing[r.config] = timing.get(r.config, 0.0) + r.wall_s
    headers = [
        "experiment",
        "learner",
        "K",
        "N",
        "converged",
        "first success",
        "episodes to converge",
        "final max steps",
        "final success rate",
        "s / run",
    ]
    rows, curves = [], {}
    for exp, cs in plan.items():
        curves[exp] = []
        for c in cs:
            ss = [by_run[(c, s)].summary for s in seeds]
            conv = [s.episodes_to_converge for s in ss if s.episodes_to_converge is not None]
            rows.append(
                [
                    exp,
                    c.algorithm.upper(),
                    c.n_agents,
                    c.share_every or "–",
                    f"{len(conv)}/{len(ss)}",
                    first_success(ss),
                    fmt_pm(conv, 0),
                    fmt_pm([s.final_steps for s in ss]),
                    fmt_pm([s.final_success for s in ss], 2),
                    f"{timing[c] / len(seeds):.1f}",
                ]
            )
            curves[exp].append((c.label, [by_run[(c, s)].result.metrics.steps for s in seeds]))
    return markdown_table(headers, rows), curves


def summary_md(seeds, episodes: int, map_seed: int, tail: int, window: int, table: str,
               experiments) -> str:  # fmt: skip
    """summary.md (and results.md) of `skyherd train sql`."""
    return (
        f"# skyherd train sql\n\n{len(seeds)} seeds {list(seeds)}, {episodes} "
        f"episodes per run, map seed {map_seed}. Final values: mean over the last {tail} "
        f"episodes; convergence: {window}-episode moving average settled within 10 % of the "
        f"final value, counted only for runs with final success rate >= 0.9. "
        f"Mean ± std over seeds (converged seeds only for episodes to converge).\n\n"
        + table
        + "\nPlots: "
        + ", ".join(f"curves_{e}.png" for e in experiments)
        + "\n"
    )


def plot_curves(path, title, curves, window, max_steps) -> None:
    """Learning curves: moving-average max steps per episode, log y; the mean over seeds, and
    the min–max band only when there are 2 seeds or more. Each curve has its own line style,
    so curves that coincide (e.g. every learner still at the step limit) stay visible and named."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skyherd.policy.sql.metrics import moving_average

    fig, ax = plt.subplots(figsize=(8, 4.8))
    styles = ("-", "--", ":", "-.")
    seeds = {len(runs) for _, runs in curves}
    for k, (label, runs) in enumerate(curves):
        ma = np.stack([moving_average(r, window) for r in runs])
        x = np.arange(window, window + ma.shape[1])
        mean = ma.mean(axis=0)
        n = len(runs)
        (line,) = ax.plot(x, mean, styles[k % len(styles)], lw=1.4 + 0.6 * (k % 2),
                          label=f"{label} ({n} seed{'s' if n != 1 else ''})")  # fmt: skip
        if n > 1:
            ax.fill_between(x, ma.min(axis=0), ma.max(axis=0), color=line.get_color(), alpha=0.2)
    stuck = [label for label, runs in curves if min(min(r) for r in runs) >= max_steps]
    if stuck:  # lines that lie on the step limit, on top of one another: named
        ax.text(0.01, 0.02, "at the step limit in every episode: " + ", ".join(stuck),
                transform=ax.transAxes, fontsize=8, va="bottom")  # fmt: skip
    ax.axhline(max_steps, color="grey", lw=0.8, ls=":", label=f"step limit ({max_steps})")
    ax.set_yscale("log")
    ax.set_ylim(top=max_steps * 1.3)
    ax.set_xlabel("episode")
    ax.set_ylabel(f"largest agent step count ({window}-episode mean)")
    band = "band: min–max over seeds" if max(seeds, default=1) > 1 else "one seed: no band"
    ax.set_title(f"{title}  (line: mean over seeds; {band})", fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
