"""`skyherd evaluate`'s report: the pre-registered evaluation's table (mean ± per-episode
standard error per policy), each composite goal held or not, and summary.md."""

from __future__ import annotations

from skyherd.runio.runfolder import markdown_table


def table(res: dict) -> str:
    """One row per policy of policy.education.prereg.evaluate's result `res`."""
    rows = []
    for name, summ in res["summary"].items():
        a, f = summ["all_in_view_frac"], summ["footprint_ratio"]
        rows.append([name, f"{a['mean']:.4f} ± {a['se']:.4f}", f"{f['mean']:.3f} ± {f['se']:.3f}",
                     a["n"]])  # fmt: skip
    return markdown_table(["policy", "all-in-view frac", "footprint/circle", "episodes"], rows)


def verdicts(res: dict) -> str:
    return "\n".join(f"- {k}: {'holds' if v else 'FAILS'}" for k, v in res["verdicts"].items())


def summary(res: dict, scenario: str, n_educated: int) -> str:
    """summary.md: the table, the educated policies' mean, the verdicts."""
    edu = res["educated_mean_over_policies"]
    lo, hi = res["seeds"]
    return (
        f"# skyherd evaluate: pre-registered, {scenario} seeds {lo}–{hi}\n\n{table(res)}\n\n"
        f"educated (mean over {n_educated} policies): all-in-view "
        f"{edu['all_in_view_frac']:.4f}, footprint {edu['footprint_ratio']:.3f}\n\n{verdicts(res)}\n"
    )
