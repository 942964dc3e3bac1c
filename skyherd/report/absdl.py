"""`skyherd train abs-dl`'s report: loss curves (PNG), the evaluation table and its CSV, the
must-show checks and summary.md. matplotlib is imported inside the plots."""

from __future__ import annotations

from pathlib import Path

from skyherd.policy.absdl.evaluate import METRICS, Score, within
from skyherd.runio import markdown_table


def plot_curves(losses: dict[str, list[list[float]]], path: Path) -> Path:
    """Training MSE per epoch of every fit (behaviour cloning, then each DAgger round)."""
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(losses), figsize=(3.2 * len(losses), 2.8), squeeze=False)
    for ax, (name, fits) in zip(axes[0], losses.items()):
        for i, curve in enumerate(fits):
            ax.plot(range(1, len(curve) + 1), curve, label="cloning" if i == 0 else f"DAgger {i}")
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("epoch")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("MSE (scaled command)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_scores(scores: list[Score], path: Path) -> Path:
    import matplotlib.pyplot as plt

    names = [s.name for s in scores]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3))
    for ax, m in zip(axes, ("all_in_view_frac", "footprint_ratio", "jerk_flown")):
        ax.bar(names, [s.mean[m] for s in scores], yerr=[s.std[m] for s in scores], capsize=3)
        ax.set_title(m)
        ax.tick_params(axis="x", labelrotation=30, labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def score_table(scores: list[Score]) -> str:
    rows = []
    for s in scores:
        m, sd = s.mean, s.std
        rows.append([s.name, s.n, f"{m['all_in_view_frac']:.3f} ± {sd['all_in_view_frac']:.3f}",
                     f"{m['footprint_ratio']:.2f} ± {sd['footprint_ratio']:.2f}",
                     f"{s.changed}/{s.decisions} ({100 * s.changed / max(s.decisions, 1):.1f} %)",
                     f"{m['jerk_proposed']:.2f}", f"{m['jerk_flown']:.2f}"])  # fmt: skip
    head = ["policy", "episodes", "all-in-view", "footprint ratio", "net changed",
            "jerk proposed [m/s³]", "jerk flown [m/s³]"]  # fmt: skip
    return markdown_table(head, rows)


def score_rows(scores: list[Score]) -> list[dict]:
    """One CSV row per policy: the means and standard deviations of METRICS."""
    out = []
    for s in scores:
        row = {"policy": s.name, "episodes": s.n, "changed": s.changed, "decisions": s.decisions}
        for m in METRICS:
            row[f"{m}_mean"], row[f"{m}_std"] = s.mean[m], s.std[m]
        out.append(row)
    return out


def checks(scores: list[Score]) -> list[tuple[str, bool, str]]:
    """The must-show checks (what, holds, the numbers) on scores in `evaluate_all`'s order."""
    ex, fu, ba, di = (s.mean for s in scores[:4])
    return [
        ("ABS-DL all-in-view within 2 % of the composite-demo network",
         within(fu["all_in_view_frac"], ba["all_in_view_frac"], 0.02),
         f"{fu['all_in_view_frac']:.3f} vs {ba['all_in_view_frac']:.3f}"),
        ("ABS-DL footprint ratio closer to the expert's than discrete AB's",
         abs(fu["footprint_ratio"] - ex["footprint_ratio"])
         < abs(di["footprint_ratio"] - ex["footprint_ratio"]),
         f"{fu['footprint_ratio']:.2f} vs expert {ex['footprint_ratio']:.2f}, AB {di['footprint_ratio']:.2f}"),
        ("ABS-DL decisions the net changes below 10 %", fu["changed"] < 0.10,
         f"{100 * scores[1].changed / scores[1].decisions:.2f} % vs AB "
         f"{100 * scores[3].changed / scores[3].decisions:.1f} %"),
        ("ABS-DL mean commanded jerk below discrete AB's", fu["jerk_proposed"] < di["jerk_proposed"],
         f"{fu['jerk_proposed']:.2f} vs {di['jerk_proposed']:.2f} m/s³"),
    ]  # fmt: skip


def summary(p, scores: list[Score], variants: list, results: list, recorded: dict) -> str:
    """summary.md: the evaluation table, the checks, the shield on the demonstrations; `p` the
    parameters (policy.absdl.params.AbsdlParams), `variants` and `results` the trainings."""
    demo_rows = []
    for v, r in zip(variants, results):
        for name, st in r.demo_shield.items():
            if v.shield:
                demo_rows.append([name, st.decisions, f"{st.changed} ({100 * st.fraction:.2f} %)",
                                  ", ".join(f"{k} {n}" for k, n in sorted(st.verdicts.items()))])  # fmt: skip
    lines = [
        f"ABS-DL on {p.eval_episodes} unseen composite episodes (seeds {p.eval_seed}–"
        f"{p.eval_seed + p.eval_episodes - 1}), every policy flown through the SafetyNet:\n",
        score_table(scores),
        "\nMust-show checks:\n",
        markdown_table(
            ["check", "holds", "numbers"],
            [[c, "yes" if ok else "NO", n] for c, ok, n in checks(scores)],
        ),
        "\nDemonstrations certified by the shield (training data):\n",
        markdown_table(["sub-task", "decisions", "net changed", "verdicts"], demo_rows),
        f"\nSamples per network (demos + DAgger): {results[0].samples}",
        f"\nParameters: `{p}`",
    ]
    if recorded:
        lines.insert(-1, f"\nRecorded demonstrations (no DAgger): {', '.join(sorted(recorded))}")
    return "\n".join(lines)
