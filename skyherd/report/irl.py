"""`skyherd train irl` / `skyherd train ab`'s report: summary.md's tables (each learner and
reference policy, mean ± std over seeds; the all-in-view fraction relative to the references;
the transfer to groundsim UGV behaviours), results.json and the figures irl_t.png and
compare.png. matplotlib is imported inside the plots."""

from __future__ import annotations

import json
import math

import numpy as np

from skyherd.runio import atomic_write_text, markdown_table


def _ms(vals) -> str | None:
    v = [x for x in vals if not (isinstance(x, float) and math.isnan(x))]
    return f"{np.mean(v):.3f} ± {np.std(v):.3f}" if v else None  # shown as — by the table


def summary(results, base, learner, args) -> tuple[str, str]:
    learners = sorted({r["learner"] for r in results}, key=lambda s: (s != "irl", s))
    rows = []
    by = {k: [r for r in results if r["learner"] == k] for k in learners}
    for k in learners:
        rs = by[k]
        rows.append(
            [
                k,
                _ms([r["metrics"]["all_in_view_frac"] for r in rs]),
                _ms([r["metrics"]["footprint_ratio"] for r in rs]),
                _ms([r["metrics"]["ugv_losses"] for r in rs]),
                _ms([r["train_s"] for r in rs]),
                _ms([r.get("train_cpu_s", math.nan) for r in rs]),
                _ms([r["history"][-1]["t"] for r in rs]),
            ]
        )
    for k, ms in base.items():
        rows.append(
            [
                k,
                _ms([m["all_in_view_frac"] for m in ms]),
                _ms([m["footprint_ratio"] for m in ms]),
                _ms([m["ugv_losses"] for m in ms]),
                "-",
                "-",
                "-",
            ]
        )
    table = markdown_table(
        [
            "policy",
            "all-in-view frac",
            "footprint/circle",
            "UGV losses / ep",
            "train wall [s]",
            "train CPU [s]",
            "final t",
        ],
        rows,
    )
    view = lambda k: np.mean([r["metrics"]["all_in_view_frac"] for r in by[k]])  # noqa: E731
    exp_d = np.mean([m["all_in_view_frac"] for m in base["expert (demonstrator)"]])
    exp_i = np.mean([m["all_in_view_frac"] for m in base["expert (ideal)"]])
    ratios = []
    for k in learners:
        row = [k, f"{view(k) / exp_d:.3f}", f"{view(k) / exp_i:.3f}"]
        row.append(f"{view(k) / view('irl'):.3f}" if "irl" in by and k != "irl" else "-")
        ratios.append(row)
    rtable = markdown_table(["learner", "÷ demonstrator", "÷ ideal expert", "÷ IRL"], ratios)
    md = (
        f"# skyherd train {learner}\n\nComposite task (scenario 4), {args.seeds} seeds, "
        f"{args.eval_episodes} test episodes per policy (seeds 100000+), mean ± std over seeds.\n"
        f"DQN {args.dqn_steps} steps per IRL iteration, at most {args.irl_iters} iterations, ε = {args.epsilon}.\n\n"
        f"{table}\nAll-in-view fraction relative to the references:\n\n{rtable}\n"
        "Plots: irl_t.png (t per iteration), compare.png (metrics per policy).\n"
    )
    return md, table + "\n" + rtable


def progress_note(done: int, jobs: int) -> str:
    """summary.md while the learners train."""
    return (
        f"{done} of {jobs} training runs finished "
        f"(learner × seed); results so far in metrics.csv and events.jsonl.\n"
    )


def transfer_md(rows: list[list], episodes: int) -> str:
    """summary.md's transfer section (policy.irl_experiment.transfer_rows)."""
    ttable = markdown_table(
        ["policy", "scenario", "all-in-view frac", "footprint/circle", "UGV losses / ep"], rows
    )
    return (
        "\n## Transfer: best seed of each learner on groundsim UGV behaviours\n\n"
        f"{episodes} episodes each (not trained on these).\n\n{ttable}"
    )


def write(rf, learned, base, learner, args, warnings, quick, transfer) -> str:
    """summary.md (with the budget's warnings, what --quick set and the `transfer` rows, if
    any), results.json and the plots into run folder `rf`; returns the tables printed."""
    md, table = summary(learned, base, learner, args)
    if warnings:
        md += "\n## Warnings\n\n" + "\n".join(f"- {w}" for w in warnings) + "\n"
    if quick:
        md += f"\n--quick budget: {', '.join(quick)}.\n"
    if transfer is not None:
        md += transfer_md(transfer, args.transfer_episodes)
    rf.summary(md)
    atomic_write_text(rf.file("results.json"), json.dumps(
        {"learned": learned, "baselines": base}, indent=1, default=float))  # fmt: skip
    plots(rf, learned, base)
    return table


def plots(rf, results, base) -> None:
    """irl_t.png (the IRL margin per iteration, one line per learner and seed) and compare.png
    (each metric per policy, mean ± std over seeds; learned and reference policies coloured
    apart)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    fig, ax = plt.subplots(figsize=(7, 4))
    learners = sorted({r["learner"] for r in results}, key=lambda s: (s != "irl", s))
    colors = dict(zip(learners, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    first_seed = min(x["seed"] for x in results)
    for r in results:
        its = [0] + [h["i"] for h in r["history"]]
        ts = [r["t0"]] + [h["t"] for h in r["history"]]
        ax.plot(its, ts, "-o", ms=3, color=colors[r["learner"]], alpha=0.7,
                label=r["learner"] if r["seed"] == first_seed else None)  # fmt: skip
    ax.set_xlabel("IRL iteration i (0 = the random start policy)")
    ax.set_ylabel("margin t = ‖μ_E − μ̄‖₂ (no unit)")
    ax.set_yscale("log")
    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.grid(True, which="both", alpha=0.3)
    n_seeds = len({r["seed"] for r in results})
    ax.set_title(f"projection IRL margin per iteration ({n_seeds} seed(s), one line each)")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0, title="learner")
    fig.tight_layout()
    fig.savefig(rf.file("irl_t.png"), dpi=100)
    plt.close(fig)

    names = learners + list(base)
    vals = {k: [r["metrics"] for r in results if r["learner"] == k] for k in learners} | base
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.4))
    for ax, key, lab, unit in zip(
        axes,
        ("all_in_view_frac", "footprint_ratio", "ugv_losses"),
        ("all-in-view fraction", "footprint / smallest circle", "UGV losses per episode"),
        ("fraction of steps", "ratio (1 = tightest)", "losses / episode"),
    ):
        m = [np.nanmean([x[key] for x in vals[k]]) for k in names]
        s = [np.nanstd([x[key] for x in vals[k]]) for k in names]
        col = ["tab:blue" if k in learners else "tab:gray" for k in names]
        ax.bar(range(len(names)), m, yerr=s, capsize=3, color=col)
        ax.set_xticks(range(len(names)), names, rotation=35, ha="right", fontsize=8)
        ax.set_title(lab)
        ax.set_ylabel(unit)
    from matplotlib.patches import Patch

    fig.legend(handles=[Patch(color="tab:blue", label="learned"),
                        Patch(color="tab:gray", label="reference (expert, random)")],
               loc="upper right", ncol=2, fontsize=8)  # fmt: skip
    fig.suptitle(
        f"composite task, mean ± std over {n_seeds} seed(s)", x=0.01, ha="left", fontsize=10
    )
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(rf.file("compare.png"), dpi=100)
    plt.close(fig)
