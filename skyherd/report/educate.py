"""`skyherd educate`'s report: summary.md (lesson by lesson, retention of the skill lessons,
the arbiters learnt, unseen test episodes, explanation fidelity, one episode's timeline) and the
figures lessons.png and compare.png. matplotlib is imported inside the plots."""

from __future__ import annotations

import math

import numpy as np

from skyherd.runio.runfolder import markdown_table


def _ms(vals) -> str:
    v = [x for x in vals if not (isinstance(x, float) and math.isnan(x))]
    return f"{np.mean(v):.3f} ± {np.std(v):.3f}" if v else "n/a"


def _retention_rows(results: list[dict], learner: str) -> list[list]:
    """Per skill lesson: score after its own lesson, just before the composite, after it."""
    rows = []
    results = [r for r in results if learner in r]  # the monolith may be on fewer seeds
    if not results:
        return rows
    names = [r["lesson"] for r in results[0][learner]]
    skills, comp = names[:-1], names[-1]
    for le in skills:
        own = [
            next(r for r in res[learner] if r["lesson"] == le)["retention"][le] for res in results
        ]
        before = [res[learner][-2]["retention"][le] for res in results]
        after = [res[learner][-1]["retention"][le] for res in results]
        passed = sum(res[learner][-1]["passed"][le] for res in results)
        rows.append([learner, le,
                     _ms([m["all_in_view_frac"] for m in own]), _ms([m["all_in_view_frac"] for m in before]),
                     _ms([m["all_in_view_frac"] for m in after]),
                     _ms([m["footprint_ratio"] for m in before]), _ms([m["footprint_ratio"] for m in after]),
                     f"{passed}/{len(results)}"])  # fmt: skip
    _ = comp
    return rows


def summary(cur, p, args, results, comparison, fid, rf) -> str:
    """summary.md: lesson by lesson, retention, the arbiters, the unseen test episodes, the
    explanations' fidelity and the timeline of one test episode (rf's decisions.jsonl)."""
    from skyherd.policy.education.timeline import read_decisions, timeline

    md = [f"# skyherd educate {cur.name} {cur.version}\n",
          f"Curriculum `{cur.path}` (sha256 {cur.sha256[:16]}…), {len(results)} seeds "
          f"(monolithic DQN on {sum('monolith' in r for r in results)}), "
          f"DQN {p.dqn.total_steps} steps per solve, {p.irl_iters} IRL iterations per lesson, "
          f"lesson re-tests on {p.test_episodes} episodes (seeds {p.test_seed}+).\n"]  # fmt: skip
    # lesson by lesson (seed means)
    rows = []
    for learner in ("educated", "monolith"):
        rs = [r for r in results if learner in r]
        if not rs:
            continue
        for k, r0 in enumerate(rs[0][learner]):
            for tested in r0["retention"]:
                ms = [res[learner][k]["retention"][tested] for res in rs]
                ok = sum(res[learner][k]["passed"][tested] for res in rs)
                rows.append([learner, r0["lesson"], tested, _ms([m["all_in_view_frac"] for m in ms]),
                             _ms([m["footprint_ratio"] for m in ms]), f"{ok}/{len(rs)}",
                             _ms([res[learner][k]["seconds"] for res in rs])])  # fmt: skip
    md.append("## Lesson by lesson\n\nAfter each lesson every lesson taught so far is re-tested on "
              "its own scenario (mean ± std over seeds; lessons.png).\n")  # fmt: skip
    md.append(markdown_table(["learner", "after lesson", "tested lesson", "all-in-view frac",
                              "footprint/circle", "passed", "lesson CPU [s]"], rows))  # fmt: skip
    md.append("\n## Retention of the skill lessons\n\n'own' = right after the lesson; 'before' = "
              "just before the composite lesson; 'after' = after it (educated: the whole modular "
              "policy; monolith: the one network).\n")  # fmt: skip
    rrows = _retention_rows(results, "educated") + _retention_rows(results, "monolith")
    md.append(markdown_table(["learner", "lesson", "all-in-view own", "all-in-view before",
                              "all-in-view after", "footprint before", "footprint after",
                              "passes after"], rrows))  # fmt: skip
    arbs = [
        f"- seed {res['seed']}: `{res['educated'][-1]['detail'].get('arbiter', '-')}`"
        for res in results
    ]
    md.append("\n## Arbiters learnt\n\n" + "\n".join(arbs) + "\n")
    crow = []
    for name, by in comparison.items():
        for sc, lst in by.items():
            crow.append([name, sc, len(lst), _ms([m["all_in_view_frac"] for _, m in lst]),
                         _ms([m["footprint_ratio"] for _, m in lst]), _ms([m["ugv_losses"] for _, m in lst])])  # fmt: skip
    md.append(f"\n## Unseen test episodes\n\n{args.eval_episodes} episodes per scenario (composite "
              "seeds 300000+, groundsim 200000+), mean ± std over policies (seeds).\n")  # fmt: skip
    md.append(markdown_table(["policy", "scenario", "policies", "all-in-view frac", "footprint/circle",
                              "UGV losses / ep"], crow))  # fmt: skip
    frow = [[role, r["n"], f"{r['action_rate']:.3f}", f"{r['action_rate_far']:.3f}",
             f"{r['module_rate']:.3f}"] for role, r in fid.items()]  # fmt: skip
    md.append("\n## Explanation fidelity\n\nEvery decision of the educated policies on the composite "
              "test episodes; one concept moved across a predicate's threshold (near: by "
              "0.1·max(|θ|, 0.01); far: by a random 0.02–0.5 of that scale), all others held "
              "(policy/education/fidelity.py).\n")  # fmt: skip
    md.append(markdown_table(["concept role", "interventions", "action changed (near)",
                              "action changed (far)", "module changed (near)"], frow))  # fmt: skip
    dec, _ = read_decisions(rf.file("decisions.jsonl"))
    md.append(
        "\n## Timeline of one test episode (decisions.jsonl)\n\n```\n"
        + "\n".join(timeline(dec)[:20])
        + "\n```\n"
    )
    return "\n".join(md)


def plots(rf, results, comparison) -> None:
    """lessons.png (every lesson re-tested after each lesson) and compare.png (the unseen test
    episodes per policy and scenario)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    learners = [k for k in ("educated", "monolith") if any(k in r for r in results)]
    every = results
    fig, axes = plt.subplots(2, len(learners), figsize=(5.5 * len(learners), 7.5), squeeze=False,
                             sharey="row")  # fmt: skip
    for j, learner in enumerate(learners):
        results = [r for r in every if learner in r]  # the monolith may be on fewer seeds
        after = [r["lesson"] for r in results[0][learner]]
        tested_all = list(results[0][learner][-1]["retention"])
        for i, (key, lab) in enumerate((("all_in_view_frac", "all-in-view fraction"),
                                        ("footprint_ratio", "footprint / smallest circle"))):  # fmt: skip
            ax = axes[i][j]
            for tested in tested_all:
                xs, ms, ss = [], [], []
                for k, _ in enumerate(after):
                    vals = [
                        res[learner][k]["retention"].get(tested, {}).get(key) for res in results
                    ]
                    vals = [v for v in vals if v is not None and not math.isnan(v)]
                    if vals:
                        xs.append(k)
                        ms.append(np.mean(vals))
                        ss.append(np.std(vals))
                ax.errorbar(xs, ms, yerr=ss, marker="o", capsize=3, label=f"test: {tested}")
            ax.set_xticks(range(len(after)), [f"after\n{a}" for a in after])
            ax.set_ylabel(lab)
            ax.set_title(f"{learner}: {lab}")
            ax.grid(alpha=0.3)
            if i == 0:
                ax.set_ylim(-0.02, 1.05)
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=len(labels), fontsize=9)
    fig.suptitle(
        "lesson by lesson: every lesson re-tested after each lesson (mean ± std over seeds)"
    )
    fig.tight_layout(rect=(0, 0.05, 1, 1))
    fig.savefig(rf.file("lessons.png"), dpi=100)
    plt.close(fig)

    names = list(comparison)
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    scen = list(next(iter(comparison.values())))
    width = 0.8 / max(len(names), 1)
    for ax, key, lab in zip(axes, ("all_in_view_frac", "footprint_ratio"),
                            ("all-in-view fraction", "footprint / smallest circle (lower = tighter)")):  # fmt: skip
        for n, name in enumerate(names):
            m = [np.nanmean([x[key] for _, x in comparison[name][sc]]) for sc in scen]
            s = [np.nanstd([x[key] for _, x in comparison[name][sc]]) for sc in scen]
            ax.bar(np.arange(len(scen)) + n * width, m, width, yerr=s, capsize=2, label=name)
        ax.set_xticks(
            np.arange(len(scen)) + 0.4 - width / 2, [s.replace("groundsim:", "gs:") for s in scen]
        )
        ax.set_title(lab)
        if key == "footprint_ratio":
            ax.set_yscale("log")  # ratios of 5 to 100 side by side
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(rf.file("compare.png"), dpi=100)
    plt.close(fig)
