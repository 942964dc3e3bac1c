"""`skyherd drill`: geofence and envelope-violation drills in SITL behind the safety net.

Runs the real autopilot in-process (OFFBOARD, simulation clock, as fast as possible) with an
adversarial scripted AI per drill, prints a table, writes a run folder (config.json with the
constraint-set version, events.jsonl, metrics.csv, summary.md, one PNG per drill) and exits 1
if any drill fails.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

import numpy as np

from skyherd.runio import ports
from skyherd.runio.constants import MISSION_DRILL_INSTANCE, TARGET_BOUND
from skyherd.runio.runfolder import RunFolder, markdown_table
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
    cols = [
        "drill",
        "airframe",
        "passed",
        "excursion_m",
        "fallback_s",
        "pid_s",
        "recover_s",
        "rejected",
        "projected",
        "switches",
        "first_reason",
        "why",
        "constraint_set_version",
    ]
    metrics = run_dir.metrics(cols)
    results = []
    total = sum(len(s[-1]) for s in plans)
    with tqdm(total=total, desc="drills", unit="drill") as bar:
        for airframe, spec, sp, p, make, scripts in plans:
            for script in scripts:
                tagged = _Tagged(events, script.name, airframe)
                r = run_drill(script, make(args.seed), spec, sp, p, tagged)
                results.append((r, spec))
                metrics.write(
                    {
                        "drill": r.name,
                        "airframe": r.airframe,
                        "passed": r.passed,
                        "excursion_m": round(r.excursion_m, 3),
                        "fallback_s": round(r.fallback_s, 3),
                        "pid_s": round(r.pid_s, 3),
                        "recover_s": "" if math.isnan(r.recover_s) else round(r.recover_s, 3),
                        "rejected": r.rejected,
                        "projected": r.projected,
                        "switches": r.switches,
                        "first_reason": r.reasons[0] if r.reasons else "",
                        "why": r.why,
                        "constraint_set_version": spec.version,
                    }
                )
                if not args.no_plots and not r.name.startswith("random"):
                    _plot(r, spec, run_dir.file(_slug(f"{airframe}-{r.name}") + ".png"))
                bar.update(1)
    events.close()
    metrics.close()
    if not args.no_plots and args.random:
        for airframe, spec, *_ in plans:
            rs = [r for r, s in results if r.airframe == airframe and r.name.startswith("random")]
            if rs:
                _plot_many(rs, spec, run_dir.file(f"{airframe}-random.png"))

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
            "pass" if r.passed else f"FAIL ({_first(r)})",
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
                f"random x{len(rnd)} (seed {args.seed})",
                "/".join(sorted({r.airframe for r in rnd})),
                f"{sum(r.passed for r in rnd)}/{len(rnd)} pass",
                max(r.excursion_m for r in rnd),
                sum(r.fallback_s + r.pid_s for r in rnd),
                f"max {max(rec):.1f}" if rec else "-",
                sum(r.rejected for r in rnd),
                f"{len(trig)} triggered a fallback",
            ]
        )
    table = markdown_table(headers, rows)
    n_fail = sum(not r.passed for r, _ in results)
    breaches = sum(_first(r) == "fence" for r, _ in results)
    worst = max(r.excursion_m for r, _ in results) if results else math.nan
    totals = (f"{len(results)} drills judged by safety.judge, {len(results) - n_fail} passed, "
              f"{n_fail} failed a check; ground-truth breaches beyond the tolerance: {breaches}; "
              f"worst excursion {worst:.2f} m (negative = stayed inside)")  # fmt: skip
    versions = ", ".join(f"{a}: {s.name} {s.version}" for a, s, *_ in plans)
    print(table)
    print(totals)
    print(f"constraint sets: {versions}")
    print(f"run folder: {run_dir.path}")
    fails = [f"- {r.name}: {r.why}" for r, _ in results if not r.passed]
    run_dir.write_summary(
        f"# skyherd drill\n\nConstraint sets: {versions}\n\n{table}\n{totals}\n"
        + ("\n## Failures\n" + "\n".join(fails) + "\n" if fails else "")
    )
    _mcap(run_dir.path)
    return 1 if n_fail else 0


def _first(r) -> str:
    """The name of a drill's first failed check ("" if it passed)."""
    return next((c.name for c in r.checks if not c.ok), "")


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


_COLORS = {0: "tab:blue", 1: "tab:red", 2: "tab:orange"}


def _draw_fence(ax, spec) -> None:
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


def _plot(r, spec, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 4.5))
    _draw_fence(a1, spec)
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


def _plot_many(rs, spec, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 6.5))
    _draw_fence(ax, spec)
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
