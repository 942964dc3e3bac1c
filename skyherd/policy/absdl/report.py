"""The run folder's report: loss curves (PNG), the evaluation table and its CSV, summary text."""

from __future__ import annotations

from pathlib import Path

from skyherd.policy.absdl.evaluate import METRICS, Score
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
