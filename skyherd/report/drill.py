"""`skyherd drill`'s report: its tables, summary.md and figures (one per scripted drill, the
random drills' tracks, the campaign's closest approaches and tracks), flight.mcap of the drills.
matplotlib is imported inside the plots. The metrics.csv rows are safety.drill_run's (named and
random drills) and safety.campaign_run's (the campaign)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from skyherd.runio.runfolder import markdown_table
from skyherd.safety.campaign_run import PLOT_TRACKS

THROUGH_TEXT = {
    "mission": "the companion's mission code (mission.flight.SingleVehicleMission, DrillPilot) "
    "over loopback MAVLink to the built-in vehicle, lockstep on the simulation clock",
    "process": "the in-process drill loop (safety.drills.run_drill)",
}  # --through


def failed_check(r) -> str:
    """The name of a drill's first failed check ("" if it passed)."""
    return next((c.name for c in r.checks if not c.ok), "")


def drill_table(results, seed: int) -> str:
    """The drills' table: every scripted drill, every random one that failed, one row for all
    the random drills. `results`: (DrillResult, spec) pairs."""
    headers = [
        "drill",
        "airframe",
        "result",
        "excursion m",
        "fallback s",
        "recover s",
        "rejected",
        "first reason",
    ]
    shown = [r for r, _ in results if not r.name.startswith("random") or not r.passed]
    rows = [
        [
            r.name,
            r.airframe,
            "pass" if r.passed else f"FAIL ({failed_check(r)})",
            r.excursion_m,
            r.fallback_s + r.pid_s,
            "-" if math.isnan(r.recover_s) else r.recover_s,
            r.rejected,
            (r.reasons[0] if r.reasons else "-")[:40],
        ]
        for r in shown
    ]
    rnd = [r for r, _ in results if r.name.startswith("random")]
    if rnd:
        trig = [r for r in rnd if r.switches]
        rec = [r.recover_s for r in rnd if not math.isnan(r.recover_s)]
        rows.append(
            [
                f"random x{len(rnd)} (seed {seed})",
                "/".join(sorted({r.airframe for r in rnd})),
                f"{sum(r.passed for r in rnd)}/{len(rnd)} pass",
                max(r.excursion_m for r in rnd),
                sum(r.fallback_s + r.pid_s for r in rnd),
                f"max {max(rec):.1f}" if rec else "-",
                sum(r.rejected for r in rnd),
                f"{len(trig)} triggered a fallback",
            ]
        )
    return markdown_table(headers, rows)


def drill_totals(results) -> str:
    """One line: drills judged, passed, failed; fence breaches; the worst excursion."""
    n_fail = sum(not r.passed for r, _ in results)
    breaches = sum(failed_check(r) == "fence" for r, _ in results)
    worst = max(r.excursion_m for r, _ in results) if results else math.nan
    return (f"{len(results)} drills judged by safety.judge, {len(results) - n_fail} passed, "
            f"{n_fail} failed a check; ground-truth breaches beyond the tolerance: {breaches}; "
            f"worst excursion {worst:.2f} m (negative = stayed inside)")  # fmt: skip


def drill_summary(versions: str, table: str, totals: str, results) -> str:
    """summary.md of `skyherd drill`."""
    fails = [f"- {r.name}: {r.why}" for r, _ in results if not r.passed]
    return f"# skyherd drill\n\nConstraint sets: {versions}\n\n{table}\n{totals}\n" + (
        "\n## Failures\n" + "\n".join(fails) + "\n" if fails else ""
    )


def campaign_summary(n: int, through: str, seed: int, only: set, versions: str, table: str,
                     closest: str, proof: str, totals: str, fails: list[str]) -> str:  # fmt: skip
    """summary.md of `skyherd drill --campaign N`."""
    return (
        f"# skyherd drill --campaign {n} --through {through} (seed {seed})"
        + (f", drills {', '.join(f'{i:04d}' for i in sorted(only))} only" if only else "")
        + "\n\n"
        f"{THROUGH_TEXT[through]}\n\nConstraint sets: {versions}\n\n"
        f"{table}\n\n## Closest approaches\n\n{closest}\n\n## What it proves\n\n{proof}\n\n"
        f"{totals}\n"
        + ("\n## Drills that failed a check\n" + "\n".join(fails[:200]) + "\n" if fails else "")
    )


def versions_line(specs) -> str:
    """The constraint sets flown: `specs` maps each airframe to its EnvelopeSpec."""
    return ", ".join(f"{a}: {s.name} {s.version}" for a, s in specs.items())


def drill_report(results, specs, seed: int) -> tuple[str, str]:
    """(what `skyherd drill` prints, its summary.md): the drills' table, the totals, the
    constraint sets (`specs`: airframe → EnvelopeSpec)."""
    table = drill_table(results, seed)
    totals = drill_totals(results)
    versions = versions_line(specs)
    printed = f"{table}\n{totals}\nconstraint sets: {versions}"
    return printed, drill_summary(versions, table, totals, results)


def campaign_report(
    rows: list[dict], specs, n: int, through: str, seed: int, only: set, target: float
) -> tuple[str, str]:
    """(what `skyherd drill --campaign N` prints, its summary.md): safety.campaign_verdict's
    tables and bounds over the drills' rows, the way they flew, the constraint sets (`specs`:
    airframe → EnvelopeSpec), the drills that failed a check."""
    from skyherd.safety.campaign_verdict import bounds, drill_passed, summarize

    table, closest, totals, _ = summarize(rows) if rows else ("", "", "no in-process drills", 0)
    proof = bounds(rows, target) if rows else ""
    versions = versions_line(specs)
    flown = f"flown through: {THROUGH_TEXT[through]}"
    printed = "\n".join([table, closest, proof, totals, flown, f"constraint sets: {versions}"])
    fails = [f"- {r['drill']} ({r['airframe']}): {r['why']}" for r in rows if not drill_passed(r)]
    facts = (versions, table, closest, proof, totals, fails)
    return printed, campaign_summary(n, through, seed, only, *facts)


def write_mcap(folder: Path) -> str:
    """flight.mcap of the drills (their metrics, events and envelope; record.from_run), so a
    drill opens in Foxglove like a flight; the line that says so. A recording that fails never
    fails the drills: the line says why."""
    try:
        from skyherd.record.from_run import mcap_from_run

        res = mcap_from_run(folder)
        return f"flight.mcap: {sum(res.counts.values())} messages"
    except Exception as e:  # noqa: BLE001 - say so, keep the drills' result
        return f"no flight.mcap ({type(e).__name__}: {e})"


def figure_name(airframe: str, drill: str) -> str:
    """A scripted drill's figure: <airframe>-<drill>.png, every other character a dash."""
    slug = "".join(c if c.isalnum() else "-" for c in f"{airframe}-{drill}").strip("-")
    return slug + ".png"


def plot_randoms(results, specs, folder: Path) -> None:
    """One figure of the random drills per airframe: <airframe>-random.png."""
    for airframe, spec in specs.items():
        rs = [r for r, _ in results if r.airframe == airframe and r.name.startswith("random")]
        if rs:
            plot_random(rs, spec, folder / f"{airframe}-random.png")


_COLORS = {0: "tab:blue", 1: "tab:red", 2: "tab:orange"}


def draw_fence(ax, spec) -> None:
    for z in spec.inclusions:
        pts = np.vstack([z.points, z.points[:1]])
        ax.plot(pts[:, 1], pts[:, 0], "k-", lw=1.5)
    for z in spec.exclusions:
        pts = np.vstack([z.points, z.points[:1]])
        ax.fill(pts[:, 1], pts[:, 0], color="0.7", alpha=0.6)
    if spec.limits.home_radius_m > 0:
        a = np.linspace(0, 2 * np.pi, 100)
        ax.plot(
            spec.limits.home_radius_m * np.sin(a),
            spec.limits.home_radius_m * np.cos(a),
            "k:",
            lw=0.8,
        )


def plot_drill(r, spec, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    draw_fence(a1, spec)
    pos, mode, t = r.track["pos"], r.track["mode"], r.track["t"]
    for m, lab in ((0, "AI"), (1, "fallback (HOLD)"), (2, "recovery PID")):
        sel = mode == m
        if sel.any():
            a1.scatter(pos[sel, 1], pos[sel, 0], s=2, color=_COLORS[m], label=lab)
            a2.scatter(t[sel], -pos[sel, 2], s=2, color=_COLORS[m])
    lo, hi = pos[:, :2].min(axis=0) - 30.0, pos[:, :2].max(axis=0) + 30.0
    a1.set_xlim(lo[1], hi[1])
    a1.set_ylim(lo[0], hi[0])
    a1.set_xlabel("east [m]")
    a1.set_ylabel("north [m]")
    a1.set_aspect("equal")
    a1.legend(loc="lower left", fontsize=7, markerscale=4)
    a1.set_title(
        f"{r.name} ({r.airframe}): {'pass' if r.passed else 'FAIL'}, excursion {r.excursion_m:.2f} m"
    )
    a2.axhline(spec.limits.ceiling_m, color="k", lw=1)
    a2.axhline(spec.limits.floor_m, color="k", lw=1)
    a2.set_xlabel("time since hand-over [s]")
    a2.set_ylabel("altitude [m]")
    a2.set_title("altitude (lines: ceiling, floor)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_random(rs, spec, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    draw_fence(ax, spec)
    for r in rs:
        pos, mode = r.track["pos"], r.track["mode"]
        ax.plot(pos[:, 1], pos[:, 0], lw=0.4, color="tab:blue", alpha=0.5)
        sel = mode != 0
        ax.scatter(pos[sel, 1], pos[sel, 0], s=0.5, color="tab:red")
    ax.set_aspect("equal")
    ax.set_xlabel("east [m]")
    ax.set_ylabel("north [m]")
    ax.set_title(f"{len(rs)} random drills: track (blue), safety net flying (red)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_campaign(rows, tracks, specs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    afs = sorted(specs)
    fig, axs = plt.subplots(2, len(afs), figsize=(7 * len(afs), 11), squeeze=False)
    for j, a in enumerate(afs):
        rs = [r for r in rows if r["airframe"] == a]
        kinds = sorted({r["kind"] for r in rs})
        ax = axs[0, j]
        for i, k in enumerate(kinds):
            c = np.array([r["min_clearance_m"] for r in rs if r["kind"] == k])
            x = i + np.random.default_rng(i).uniform(-0.25, 0.25, len(c))
            ax.scatter(x, c, s=4, alpha=0.6)
        ax.axhline(0.0, color="r", lw=1)
        ax.set_xticks(range(len(kinds)))
        ax.set_xticklabels(kinds, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("closest approach to the fence [m] (< 0 = breach)")
        ax.set_title(f"{a}: {len(rs)} drills, {sum(r['breach'] for r in rs)} breaches, "
                     f"{sum(r['overridden'] for r in rs)} overridden failsafes")  # fmt: skip
        ax2 = axs[1, j]
        draw_fence(ax2, specs[a])
        for _k, tr in tracks[a][:PLOT_TRACKS]:
            t = np.asarray(tr)
            if len(t):
                ax2.plot(t[:, 1], t[:, 0], lw=0.3, alpha=0.4)
        ax2.set_aspect("equal")
        ax2.set_xlabel("east [m]")
        ax2.set_ylabel("north [m]")
        ax2.set_title(f"{a}: tracks of the first {min(PLOT_TRACKS, len(tracks[a]))} drills")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
