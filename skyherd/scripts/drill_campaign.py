"""`skyherd drill --campaign N`: the command line of the drill campaign — its run folder,
progress bar and printing; its summary.md and plot are report.drill's. The drills, their rows
and the campaign's verdict live below: mission.campaign (the runner: `--through
mission|process`, `--workers`, `--backend`, `--ray-address`), safety.campaign_run (one drill →
its metrics.csv row), safety.campaign_verdict (the exit rule `failed_drills`, the tables
`summarize`, what the campaign proves `bounds`).

Writes a run folder: config.json, metrics.csv (one row per drill, flushed as drills finish),
events.jsonl (every switch, yield and parameter verdict, tagged with the drill), campaign.png
(closest approach per drill and kind), summary.md (the tables and the closest approaches).
Exit 1 when any drill failed a check or crashed.
"""

from __future__ import annotations

from pathlib import Path

from skyherd.report import drill as report
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
        report.plot_campaign(
            rows, tracks, {a: s for a, (s, _) in specs.items()}, run_dir.file("campaign.png")
        )
    versions = ", ".join(f"{a}: {s.name} {s.version}" for a, (s, _) in specs.items())
    print(table)
    print(closest)
    print(proof)
    print(totals)
    print(f"flown through: {report.THROUGH_TEXT[through]}")
    print(f"constraint sets: {versions}")
    print(f"run folder: {run_dir.path}")
    fails = [f"- {r['drill']} ({r['airframe']}): {r['why']}" for r in rows if not drill_passed(r)]
    run_dir.write_summary(report.campaign_summary(n, through, args.seed, only, versions, table,
                                                  closest, proof, totals, fails))  # fmt: skip
    return 1 if failed_drills(rows) else 0
