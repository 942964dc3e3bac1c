"""`skyherd drill`: geofence and envelope-violation drills in SITL behind the safety net.

Runs the real autopilot in-process (OFFBOARD, simulation clock, as fast as possible) with an
adversarial scripted AI per drill, prints a table, writes a run folder (config.json with the
constraint-set version, events.jsonl, metrics.csv, summary.md, one PNG per drill) and exits 1
if any drill fails.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

from skyherd.report import drill as report
from skyherd.runio import ports
from skyherd.runio.constants import MISSION_DRILL_INSTANCE, TARGET_BOUND
from skyherd.runio.runfolder import RunFolder
from skyherd.scripts.cli import UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--airframe",
        choices=["quadrotor", "fixedwing", "all"],
        default="quadrotor",
        help="airframe to drill (default quadrotor)",
    )
    parser.add_argument(
        "--random",
        type=int,
        default=0,
        metavar="N",
        help="also run N random drills (random states, actions pushing toward the boundaries)",
    )
    parser.add_argument("--seed", type=int, default=0, help="seed of the random drills (default 0)")
    parser.add_argument(
        "--only",
        default=None,
        metavar="NAME",
        help="run only the scripted drills whose name contains NAME (comma-separated list)",
    )
    parser.add_argument(
        "--envelope",
        type=Path,
        default=None,
        help="constraint-set TOML (default safety/envelopes/<airframe>_field.toml)",
    )
    parser.add_argument(
        "--intervention",
        choices=["switch", "project"],
        default=None,
        help="unsafe action → fallback (switch) or closest safe action first (project)",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        help="AI time per drill [s] (default 35 quadrotor, 90 fixed-wing; a drill that must "
        "end with the AI flying runs at least its attack + the airframe's recovery allowance, "
        "5 s quadrotor, 46 s fixed-wing)",
    )
    parser.add_argument(
        "--runs-dir", type=Path, default=Path("runs"), help="where run folders go (default runs/)"
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNGs")
    parser.add_argument(
        "--campaign",
        type=int,
        default=0,
        metavar="N",
        help="run N randomized adversarial drills per airframe (safety.campaign: max speed, "
        "oscillation, repeat offender, link loss, GPS glitch, wind, battery, parameter "
        "sabotage) instead of the named drills; --airframe all for both",
    )
    parser.add_argument(
        "--drill", type=int, nargs="+", default=[], metavar="INDEX", dest="campaign_drills",
        help="--campaign: fly only these drills of the campaign (its index, e.g. 664 for drill "
        "0664 of the summary; the same seed and N fly the same drill), e.g. to look at one "
        "that failed (default: all N)",
    )  # fmt: skip
    parser.add_argument(
        "--workers", type=int, default=1,
        help="--campaign: CPUs (a local Ray instance's or the process pool's; default 1: in "
        "this process)",
    )  # fmt: skip
    parser.add_argument(
        "--backend", choices=("auto", "ray", "process"), default="auto",
        help="--campaign with --workers > 1 or --ray-address: auto = Ray if installed, else a "
        "local process pool; a dead worker's drill runs again (default auto)",
    )  # fmt: skip
    parser.add_argument(
        "--ray-address", default=None, metavar="ADDR",
        help="--campaign: run the drills as tasks on this Ray cluster (default: a local "
        "instance on loopback, when --workers > 1)",
    )  # fmt: skip
    parser.add_argument(
        "--target-bound",
        type=float,
        default=TARGET_BOUND,
        metavar="P",
        help="--campaign: the breach probability to bound (95 %% one-sided Clopper-Pearson); "
        "the report says how many breach-free drills that needs (default 1e-3: 2,995)",
    )
    parser.add_argument(
        "--through", choices=("mission", "process"), default="mission",
        help="--campaign: how each drill flies. mission: `skyherd fly`'s mission code "
        "(SingleVehicleMission with the drill's adversarial pilot, the same SafetyNet and "
        "judge) over real loopback MAVLink to the built-in vehicle, in lockstep on the "
        "simulation clock (mission.drill_link); process: the in-process drill loop "
        "(safety.drills.run_drill) (default mission)",
    )  # fmt: skip
    parser.add_argument(
        "--instance", type=int, default=MISSION_DRILL_INSTANCE,
        help=f"--through mission: the first vehicle instance ({ports.MAVLINK_PORTS_HELP}); each drill running at once takes the next free one, up to N+31 (default {MISSION_DRILL_INSTANCE})",
    )  # fmt: skip


def _airframes(choice: str) -> list[str]:
    return ["quadrotor", "fixedwing"] if choice == "all" else [choice]


def _factory(airframe: str):
    """A function that returns a fresh autopilot (on the ground, or ready to start in air)."""
    try:
        from skyherd.flight.airframes_registry import AirframeUnavailable, make_autopilot
    except ImportError:  # no registry in this installation: the quadrotor directly
        from skyherd.flight.multirotor.autopilot import MultirotorAutopilot

        if airframe != "quadrotor":
            raise UsageError(
                f"no {airframe} autopilot in this installation; try --airframe quadrotor"
            ) from None
        return lambda seed: MultirotorAutopilot(seed=seed)
    try:
        make_autopilot(airframe)  # fail early if unavailable
    except AirframeUnavailable as e:
        raise UsageError(f"{e}; try --airframe quadrotor") from e
    return lambda seed: make_autopilot(airframe, seed=seed)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from skyherd.safety.drills import DrillParams, random_drill, run_drill, scripted_drills

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
    try:
        ports.check_instance(args.instance)
    except ValueError as e:
        raise UsageError(str(e)) from None
    from skyherd.scripts.drill_campaign import load_set_or_usage, run_campaign

    if args.campaign:
        return run_campaign(args)
    if args.duration is not None and not (5.0 <= args.duration <= 600.0):
        raise UsageError("--duration must be within [5, 600] s")
    plans = []
    for airframe in _airframes(args.airframe):
        spec, sp = load_set_or_usage(airframe, args.envelope)
        if args.intervention:
            sp = dataclasses.replace(sp, intervention=args.intervention)
        make = _factory(airframe)
        p = (
            DrillParams()
            if args.duration is None
            else DrillParams(duration_s=args.duration, duration_fixedwing_s=args.duration)
        )
        scripts = scripted_drills(spec, p)
        if args.only:
            keys = [k.strip() for k in args.only.split(",") if k.strip()]
            scripts = [s for s in scripts if any(k in s.name for k in keys)]
            if not scripts and not args.random:
                raise UsageError(
                    f"--only {args.only!r} matches no drill; names: {[s.name for s in scripted_drills(spec, p)]}"
                )
        rng = np.random.default_rng(args.seed)
        scripts += [random_drill(k, rng, spec, p) for k in range(args.random)]
        plans.append((airframe, spec, sp, p, make, scripts))

    run_dir = RunFolder("drill", root=args.runs_dir)
    run_dir.write_config(
        {
            "args": {k: v for k, v in vars(args).items() if not k.startswith("_")},
            "seed": args.seed,
            "plans": [
                {
                    "airframe": a,
                    "constraint_set": spec.describe(),
                    "constraint_set_version": spec.version,
                    "supervisor": sp,
                    "drill": p,
                    "drills": [s.name for s in scripts],
                }
                for a, spec, sp, p, _, scripts in plans
            ],
        }
    )
    events = run_dir.events()
    metrics = run_dir.metrics(report.COLUMNS)
    results = []
    total = sum(len(s[-1]) for s in plans)
    with tqdm(total=total, desc="drills", unit="drill") as bar:
        for airframe, spec, sp, p, make, scripts in plans:
            for script in scripts:
                tagged = _Tagged(events, script.name, airframe)
                r = run_drill(script, make(args.seed), spec, sp, p, tagged)
                results.append((r, spec))
                metrics.write(report.metrics_row(r, spec.version))
                if not args.no_plots and not r.name.startswith("random"):
                    report.plot_drill(r, spec, run_dir.file(_slug(f"{airframe}-{r.name}") + ".png"))
                bar.update(1)
    events.close()
    metrics.close()
    if not args.no_plots and args.random:
        for airframe, spec, *_ in plans:
            rs = [r for r, s in results if r.airframe == airframe and r.name.startswith("random")]
            if rs:
                report.plot_random(rs, spec, run_dir.file(f"{airframe}-random.png"))

    table = report.drill_table(results, args.seed)
    totals = report.drill_totals(results)
    n_fail = sum(not r.passed for r, _ in results)
    versions = ", ".join(f"{a}: {s.name} {s.version}" for a, s, *_ in plans)
    print(table)
    print(totals)
    print(f"constraint sets: {versions}")
    print(f"run folder: {run_dir.path}")
    run_dir.write_summary(report.drill_summary(versions, table, totals, results))
    _mcap(run_dir.path)
    return 1 if n_fail else 0


def _mcap(folder) -> None:
    """flight.mcap of the drills (their metrics, events and envelope; record.from_run), so a
    drill opens in Foxglove like a flight. A recording that fails never fails the drills."""
    try:
        from skyherd.record.from_run import mcap_from_run

        res = mcap_from_run(folder)
        print(f"flight.mcap: {sum(res.counts.values())} messages")
    except Exception as e:  # noqa: BLE001 - say so, keep the drills' result
        print(f"no flight.mcap ({type(e).__name__}: {e})")


class _Tagged:
    """Adds the drill and airframe to every supervisor event."""

    def __init__(self, sink, drill: str, airframe: str):
        self.sink, self.drill, self.airframe = sink, drill, airframe

    def write(self, record: dict) -> None:
        self.sink.write({"drill": self.drill, "airframe": self.airframe, **record})


def _slug(s: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in s).strip("-")
