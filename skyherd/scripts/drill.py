"""`skyherd drill`: geofence and envelope-violation drills behind the safety net, each judged
by `fly`'s judge: the named and random drills in-process (safety.drill_run), or `--campaign N`
randomized drills per airframe (mission.campaign, safety.campaign_run). A table, a run folder
(config.json with the constraint sets, events.jsonl, metrics.csv, summary.md, figures; the
report is report.drill's), exit 1 if any drill fails a check.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path

from skyherd.report import drill as report
from skyherd.runio import UsageError, args_dict, ports
from skyherd.runio.constants import MISSION_DRILL_INSTANCE, TARGET_BOUND
from skyherd.runio.run import open_run_folder
from skyherd.runio.runfolder import RunFolder
from skyherd.safety.campaign_run import load_set
from skyherd.scripts.cli import usage
from skyherd.scripts.options import add_options, opt


@dataclass(frozen=True)
class DrillOptions:
    """The options of `skyherd drill` (scripts.options: one field, one option)."""

    airframe: str = opt("quadrotor", choices=["quadrotor", "fixedwing", "all"])
    """airframe to drill (default quadrotor)"""
    random: int = opt(0, metavar="N")
    """also run N random drills (random states, actions pushing toward the boundaries)"""
    seed: int = 0  # seed of the random drills (default 0)
    only: str | None = opt(None, metavar="NAME")
    """run only the scripted drills whose name contains NAME (comma-separated list)"""
    envelope: Path | None = None
    """constraint-set TOML (default safety/envelopes/<airframe>_field.toml)"""
    intervention: str | None = opt(None, choices=["switch", "project"])
    """unsafe action → fallback (switch) or closest safe action first (project)"""
    duration: float | None = None
    """AI time per drill [s] (default 35 quadrotor, 90 fixed-wing; a drill that must end with
    the AI flying runs at least its attack + the airframe's recovery allowance, 5 s quadrotor,
    46 s fixed-wing)"""
    runs_dir: Path = Path("runs")  # where run folders go (default runs/)
    no_plots: bool = False  # skip the PNGs
    campaign: int = opt(0, metavar="N")
    """run N randomized adversarial drills per airframe (safety.campaign: max speed,
    oscillation, repeat offender, link loss, GPS glitch, wind, battery, parameter sabotage)
    instead of the named drills; --airframe all for both"""
    campaign_drills: tuple[int, ...] = opt((), flag="--drill", metavar="INDEX")
    """--campaign: fly only these drills of the campaign (its index, e.g. 664 for drill 0664 of
    the summary; the same seed and N fly the same drill), e.g. to look at one that failed
    (default: all N)"""
    workers: int = 1
    """--campaign: CPUs (a local Ray instance's or the process pool's; default 1: in this
    process)"""
    backend: str = opt("auto", choices=("auto", "ray", "process"))
    """--campaign with --workers > 1 or --ray-address: auto = Ray if installed, else a local
    process pool; a dead worker's drill runs again (default auto)"""
    ray_address: str | None = opt(None, metavar="ADDR")
    """--campaign: run the drills as tasks on this Ray cluster (default: a local instance on
    loopback, when --workers > 1)"""
    target_bound: float = opt(TARGET_BOUND, metavar="P")
    """--campaign: the breach probability to bound (95 %% one-sided Clopper-Pearson); the report
    says how many breach-free drills that needs (default 1e-3: 2,995)"""
    through: str = opt("mission", choices=("mission", "process"))
    """--campaign: how each drill flies. mission: `skyherd fly`'s mission code
    (SingleVehicleMission with the drill's adversarial pilot, the same SafetyNet and judge) over
    real loopback MAVLink to the built-in vehicle, in lockstep on the simulation clock
    (mission.drill_link); process: the in-process drill loop (safety.drills.run_drill) (default
    mission)"""
    resume: Path | None = opt(None, metavar="RUN")
    """--campaign: go on with the campaign of this run folder (one interrupted, killed or cut
    short): the drills it has rows for stay, the others fly and their rows are added; the
    campaign's own options (N, --seed, --airframe, --envelope, --through, --drill,
    --target-bound) are the folder's (config.json), --workers/--backend/--ray-address this
    command's; refused if a constraint set changed since"""
    instance: int = opt(
        MISSION_DRILL_INSTANCE,
        help=f"--through mission: the first vehicle instance ({ports.MAVLINK_PORTS_HELP}); each "
        f"drill running at once takes the next free one, up to N+31 (default "
        f"{MISSION_DRILL_INSTANCE})",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(parser, DrillOptions)


def _airframes(choice: str) -> list[str]:
    return ["quadrotor", "fixedwing"] if choice == "all" else [choice]


def run(args: argparse.Namespace) -> int:
    if args.random < 0:
        raise UsageError("--random must be >= 0")
    if args.campaign < 0 or not (1 <= args.workers <= 16):
        raise UsageError("--campaign must be >= 0 and --workers within [1, 16]")
    if args.campaign_drills and not all(0 <= i < args.campaign for i in args.campaign_drills):
        raise UsageError(
            f"--drill needs --campaign N and indices within [0, N), got {args.campaign_drills}"
        )
    if not 0.0 < args.target_bound < 1.0:
        raise UsageError(
            f"--target-bound must be within (0, 1), e.g. 1e-3; got {args.target_bound:g}"
        )
    usage(ports.check_instance, args.instance)
    if args.resume is not None:
        _resumed_options(args)
    if args.campaign:
        return _campaign(args)
    if args.duration is not None and not (5.0 <= args.duration <= 600.0):
        raise UsageError("--duration must be within [5, 600] s")
    plans = [_plan(airframe, args) for airframe in _airframes(args.airframe)]
    return _drills(args, plans)


def _plan(airframe: str, args: argparse.Namespace):
    from skyherd.flight.airframes_registry import AirframeUnavailable
    from skyherd.safety.drill_run import drill_plan

    spec, sp = usage(load_set, airframe, args.envelope)
    try:
        return drill_plan(
            airframe, spec, sp, args.intervention, args.duration, args.only, args.random, args.seed
        )
    except AirframeUnavailable as e:
        raise UsageError(f"{e}; try --airframe quadrotor") from e
    except ValueError as e:
        raise UsageError(f"--only {e}") from e


def _drills(args: argparse.Namespace, plans) -> int:
    """The named and random drills of `plans`: run folder, progress, figures, table, summary."""
    from tqdm import tqdm

    from skyherd.safety.drill_run import COLUMNS, fly_plans

    run_dir = open_run_folder("drill", args.runs_dir)
    plan_facts = [p.describe() for p in plans]
    run_dir.write_config({"args": args_dict(args), "seed": args.seed, "plans": plan_facts})
    events = run_dir.events()
    metrics = run_dir.metrics(COLUMNS)
    with tqdm(total=sum(len(p.scripts) for p in plans), desc="drills", unit="drill") as bar:

        def plot(plan, r) -> None:
            if not args.no_plots and not r.name.startswith("random"):
                report.plot_drill(
                    r, plan.spec, run_dir.file(report.figure_name(plan.airframe, r.name))
                )
            bar.update(1)

        results = fly_plans(plans, args.seed, events, metrics, plot)
    events.close()
    metrics.close()
    specs = {p.airframe: p.spec for p in plans}
    if not args.no_plots and args.random:
        report.plot_randoms(results, specs, run_dir.path)
    printed, summary = report.drill_report(results, specs, args.seed)
    print(printed)
    print(f"run folder: {run_dir.path}")
    run_dir.write_summary(summary)
    print(report.write_mcap(run_dir.path))
    return 1 if any(not r.passed for r, _ in results) else 0


def _resumed_options(args: argparse.Namespace) -> None:
    """--resume RUN: the campaign's own options from RUN/config.json into `args` (UsageError:
    not a campaign's folder, or one of them given again on the command line)."""
    import json

    from skyherd.mission.campaign import CAMPAIGN_OPTIONS

    config = Path(args.resume) / "config.json"
    try:
        first = json.loads(config.read_text())
        given = first["args"]
        if first.get("command") != "drill" or not given.get("campaign"):
            raise KeyError("campaign")
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise UsageError(f"--resume {args.resume}: not the run folder of a `skyherd drill "
                         f"--campaign` ({config}: {e}); pass the folder the campaign printed") from None  # fmt: skip
    defaults = DrillOptions()
    seq = lambda v: tuple(v) if isinstance(v, list) else v  # noqa: E731  (--drill: a list)
    again = [k for k in CAMPAIGN_OPTIONS if seq(getattr(args, k)) != getattr(defaults, k)]
    if again:
        flags = ", ".join("--" + ("drill" if k == "campaign_drills" else k.replace("_", "-"))
                          for k in again)  # fmt: skip
        raise UsageError(f"--resume flies the campaign as its folder says; drop {flags}")
    for k in CAMPAIGN_OPTIONS:
        v = given[k]
        setattr(args, k, Path(v) if k == "envelope" and v is not None else
                tuple(v) if k == "campaign_drills" else v)  # fmt: skip


def _campaign_folder(args, sets) -> tuple[RunFolder, list[dict]]:
    """The campaign's run folder and the rows it already holds: a new folder (config.json
    written), or --resume's (its rows read, config.json given this sitting; UsageError if a
    constraint set is not the one it flew)."""
    import datetime as dt
    import json

    from skyherd.mission.campaign import judged_rows
    from skyherd.runio.runfolder import atomic_write_text, to_jsonable

    described = {a: s.describe() for a, (s, _) in sets.items()}
    supervisor = {a: sp for a, (_, sp) in sets.items()}
    if args.resume is None:
        folder = open_run_folder("drill", args.runs_dir)
        folder.write_config({"args": args_dict(args), "seed": args.seed,
                             "campaign": args.campaign, "airframes": list(sets),
                             "constraint_sets": described, "supervisor": supervisor})  # fmt: skip
        return folder, []
    folder = RunFolder.reopen(args.resume)
    config = json.loads(folder.file("config.json").read_text())
    now = json.loads(json.dumps(to_jsonable({"c": described, "s": supervisor})))
    if now != {"c": config["constraint_sets"], "s": config["supervisor"]}:
        raise UsageError(f"--resume {args.resume}: a constraint set or the supervisor's "
                         "parameters changed since this campaign began; start a new campaign "
                         "(without --resume)")  # fmt: skip
    tols = {a: s.limits.breach_tolerance_m for a, (s, _) in sets.items()}
    rows = usage(judged_rows, folder.path, tols)
    config.setdefault("sittings", []).append(
        {"resumed_utc": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
         "argv": args._argv, "drills_judged_before": len(rows)}
    )  # fmt: skip
    atomic_write_text(
        folder.file("config.json"), json.dumps(config, indent=2, sort_keys=True) + "\n"
    )
    return folder, rows


def _campaign(args: argparse.Namespace) -> int:
    """`--campaign N`: run folder, progress, tables, plot and summary; 0 if every drill passed
    (safety.campaign_verdict.failed_drills), else 1."""
    from tqdm import tqdm

    from skyherd.mission.campaign import campaign_jobs, jobs_left, record_campaign
    from skyherd.runio.signals import KeptSignals
    from skyherd.safety.campaign_run import COLUMNS
    from skyherd.safety.campaign_verdict import failed_drills

    airframes = _airframes(args.airframe)
    sets = {a: usage(load_set, a, args.envelope) for a in airframes}
    jobs = campaign_jobs(airframes, args.campaign, args.seed, args.envelope, args.through,
                         args.instance)  # fmt: skip
    only = set(args.campaign_drills)
    if only:  # --drill: those drills of the campaign alone, as the whole campaign flies them
        jobs = [j for j in jobs if j.index in only]
    run_dir, before = _campaign_folder(args, sets)
    if args.resume is not None:
        jobs = jobs_left(jobs, before)
        print(f"skyherd drill: resuming {run_dir.path}: {len(before)} drills judged before, "
              f"{len(jobs)} to fly", flush=True)  # fmt: skip
    events = run_dir.events()
    metrics = run_dir.metrics(COLUMNS)
    wall0 = time.monotonic()
    judged = [len(before)]  # rows in metrics.csv

    def on_row(row: dict, bar) -> None:
        judged[0] += 1
        bar.update(1)

    try:  # SIGINT, SIGTERM, SIGHUP raise (whatever this process inherited): rows are kept
        with KeptSignals() as kept, tqdm(total=len(before) + len(jobs), initial=len(before),
                                         desc="campaign", unit="drill") as bar:  # fmt: skip
            kept.raising()
            rows, tracks = record_campaign(
                jobs,
                events,
                metrics,
                args.workers,
                args.backend,
                args.ray_address,
                tqdm.write,
                lambda row: on_row(row, bar),
            )
    except KeyboardInterrupt as e:  # every row written is kept: say how to go on
        return _campaign_interrupted(e, run_dir, judged[0], len(before) + len(jobs))
    finally:
        events.close()
        metrics.close()
    wall = time.monotonic() - wall0
    sitting = (f"this sitting: {len(rows)} drills in {wall:.0f} s of wall time "
               f"({len(rows) / max(wall, 1e-9):.2f} drills/s, {args.workers} worker"
               f"{'s' if args.workers > 1 else ''})"
               + (f"; {len(before)} judged in earlier sittings (--resume)" if before else ""))  # fmt: skip
    rows = before + rows
    specs = {a: s for a, (s, _) in sets.items()}
    if not args.no_plots and rows:
        report.plot_campaign(rows, tracks, specs, run_dir.file("campaign.png"))
    n, through, target = args.campaign, args.through, args.target_bound
    printed, summary = report.campaign_report(rows, specs, n, through, args.seed, only, target)
    printed, summary = f"{printed}\n{sitting}", f"{summary}\n{sitting}\n"
    print(printed)
    print(f"run folder: {run_dir.path}")
    run_dir.write_summary(summary)
    return 1 if failed_drills(rows) else 0


def _campaign_interrupted(e: KeyboardInterrupt, run_dir: RunFolder, judged: int, n: int) -> int:
    """A campaign stopped by a signal: its summary.md and a line say how many drills are judged
    and kept and how to go on (--resume); 128 + signum."""
    import shlex
    import sys

    from skyherd.runio.signals import interrupted

    rc, why = interrupted(e)
    go_on = f"skyherd drill --resume {shlex.quote(str(run_dir.path))}"
    said = (f"{judged} of {n} drills judged, their rows kept in metrics.csv; go on with "
            f"`{go_on}`")  # fmt: skip
    run_dir.write_summary(f"# skyherd drill --campaign: INTERRUPTED\n\n{why}: {said}\n")
    print(f"skyherd drill: INTERRUPTED: {why}: {said}", file=sys.stderr, flush=True)
    return rc
