"""`skyherd drill --campaign N`: the command line of the drill campaign — its run folder,
progress bar, tables, plot and summary. The drills, their rows and the campaign's verdict live
below: mission.campaign (the runner: `--through mission|process`, `--workers`, `--backend`,
`--ray-address`), safety.campaign_run (one drill → its metrics.csv row), safety.campaign_verdict
(the exit rule `failed_drills`, the tables `summarize`, what the campaign proves `bounds`).

Writes a run folder: config.json, metrics.csv (one row per drill, flushed as drills finish),
events.jsonl (every switch, yield and parameter verdict, tagged with the drill), campaign.png
(closest approach per drill and kind), summary.md (the tables and the closest approaches).
Exit 1 when any drill failed a check or crashed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from skyherd.runio.constants import MISSION_DRILL_INSTANCE
from skyherd.runio.runfolder import RunFolder
from skyherd.safety.campaign_run import COLUMNS, load_set
from skyherd.safety.campaign_verdict import (
    TARGET_BOUND,
    bounds,
    drill_passed,
    failed_drills,
    summarize,
)
from skyherd.safety.config import EnvelopeFileError
from skyherd.scripts.cli import UsageError

THROUGH_TEXT = {
    "mission": "the companion's mission code (mission.flight.SingleVehicleMission, DrillPilot) "
    "over loopback MAVLink to the built-in vehicle, lockstep on the simulation clock",
    "process": "the in-process drill loop (safety.drills.run_drill)",
}  # --through


def load_set_or_usage(airframe: str, envelope: Path | None):
    """The airframe's constraint set and supervisor parameters (safety.campaign_run.load_set);
    UsageError naming what to fix."""
    try:
        return load_set(airframe, envelope)
    except EnvelopeFileError as e:
        raise UsageError(f"{e}; fix the file or pass another --envelope") from e
    except ValueError as e:
        raise UsageError(str(e)) from e


def run_campaign(args) -> int:
    """The campaign of `args` (drill.py's options): run folder, progress, tables, plot and
    summary; 0 if every drill passed (safety.campaign_verdict.failed_drills), else 1."""
    from tqdm import tqdm

    from skyherd.mission.campaign import campaign_jobs, run_all

    airframes = ["quadrotor", "fixedwing"] if args.airframe == "all" else [args.airframe]
    specs = {a: load_set_or_usage(a, args.envelope) for a in airframes}
    n = args.campaign
    through = getattr(args, "through", "process")
    jobs = campaign_jobs(airframes, n, args.seed, args.envelope, through,
                         getattr(args, "instance", MISSION_DRILL_INSTANCE))  # fmt: skip
    only = set(getattr(args, "campaign_drills", []))
    if only:  # --drill: those drills of the campaign alone, as the whole campaign flies them
        jobs = [j for j in jobs if j.index in only]
    run_dir = RunFolder("drill", root=args.runs_dir)
    run_dir.write_config({"args": {k: v for k, v in vars(args).items() if not k.startswith("_")},
                          "seed": args.seed, "campaign": n, "airframes": airframes,
                          "constraint_sets": {a: s.describe() for a, (s, _) in specs.items()},
                          "supervisor": {a: sp for a, (_, sp) in specs.items()}})  # fmt: skip
    events = run_dir.events()
    metrics = run_dir.metrics(COLUMNS)
    rows: list[dict] = []
    tracks: dict[str, list] = {a: [] for a in airframes}

    def keep(row: dict) -> None:
        row.setdefault("_tol", 0.0)
        for e in row.pop("_events"):
            events.write({"drill": row["drill"], "airframe": row["airframe"], **e})
        tracks[row["airframe"]].append((row["kind"], row.pop("_track")))
        metrics.write(row)
        rows.append(row)

    with tqdm(total=len(jobs), desc="campaign", unit="drill") as bar:
        for row in run_all(jobs, args.workers, getattr(args, "backend", "auto"),
                           getattr(args, "ray_address", None), say=tqdm.write):  # fmt: skip
            keep(row)  # streamed to metrics.csv as drills finish
            bar.update(1)
    events.close()
    metrics.close()
    table, closest, totals, _ = summarize(rows) if rows else ("", "", "no in-process drills", 0)
    target = getattr(args, "target_bound", TARGET_BOUND)
    proof = bounds(rows, target) if rows else ""
    if not args.no_plots and rows:
        plot(rows, tracks, {a: s for a, (s, _) in specs.items()}, run_dir.file("campaign.png"))
    versions = ", ".join(f"{a}: {s.name} {s.version}" for a, (s, _) in specs.items())
    print(table)
    print(closest)
    print(proof)
    print(totals)
    print(f"flown through: {THROUGH_TEXT[through]}")
    print(f"constraint sets: {versions}")
    print(f"run folder: {run_dir.path}")
    fails = [f"- {r['drill']} ({r['airframe']}): {r['why']}" for r in rows if not drill_passed(r)]
    run_dir.write_summary(
        f"# skyherd drill --campaign {n} --through {through} (seed {args.seed})"
        + (f", drills {', '.join(f'{i:04d}' for i in sorted(only))} only" if only else "")
        + "\n\n"
        f"{THROUGH_TEXT[through]}\n\nConstraint sets: {versions}\n\n"
        f"{table}\n\n## Closest approaches\n\n{closest}\n\n## What it proves\n\n{proof}\n\n"
        f"{totals}\n"
        + ("\n## Drills that failed a check\n" + "\n".join(fails[:200]) + "\n" if fails else "")
    )
    return 1 if failed_drills(rows) else 0


def plot(rows, tracks, specs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skyherd.scripts.drill import _draw_fence

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
        _draw_fence(ax2, specs[a])
        for _k, tr in tracks[a][:400]:
            t = np.asarray(tr)
            if len(t):
                ax2.plot(t[:, 1], t[:, 0], lw=0.3, alpha=0.4)
        ax2.set_aspect("equal")
        ax2.set_xlabel("east [m]")
        ax2.set_ylabel("north [m]")
        ax2.set_title(f"{a}: tracks of the first {min(400, len(tracks[a]))} drills")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
