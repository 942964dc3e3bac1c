"""The formation mission of `skyherd fly`: K quadrotors fly the learned SQL-SIE plan.

`skyherd fly --mission formation --agents K` takes the lock-step grid plan (trained in-process
with a fixed seed, a few seconds, or read from `--policy-file`, a `plan_K<K>.json` written by
`skyherd train sql`), maps the 50×50 grid onto the field (cell (x, y) → north (y−1)·cell,
east (x−1)·cell about the field origin), and starts K+1 programs: one `skyherd sim --ugvs none`
per vehicle (instance N+k, its home on its start cell) and one `skyherd companion --mission
formation` flying all K in lockstep (mission/formation.py), every setpoint behind its vehicle's
safety net. The run folder gets plan.json, decisions.jsonl and events.jsonl (every vehicle),
metrics.csv (every position sample, field frame), uav<k>/ (each vehicle's tlog, world.csv,
sim_stats.json, sim.log), formation.png and summary.md with landing errors, separations, times.
"""

from __future__ import annotations

import argparse
import json
import math
import os
from pathlib import Path

import numpy as np

from skyherd.flight.geo import DEFAULT_HOME
from skyherd.mission.formation_plan import (
    FormationParams,
    PlanError,
    load_plan,
    plan_moves,
    plan_ne,
    plan_text,
    separation,
    tracking_error,
    validate_plan,
    vehicle_homes,
    vehicle_instances,
)
from skyherd.mission.formation_run import judge_vehicles, read_tracks
from skyherd.report.reason import flight_reason
from skyherd.runio import ports
from skyherd.runio.constants import GCS_REMOTE_PORT
from skyherd.runio.runfolder import args_dict, atomic_write_text, markdown_table
from skyherd.scripts.cli import UsageError
from skyherd.scripts.fly_options import AGENT_CHOICES, add_formation_arguments  # noqa: F401 - the options live there
from skyherd.world.fleet import FleetVehicle, write_fleet


def _params(args) -> FormationParams:
    try:
        return FormationParams(cell_m=args.cell_m)
    except ValueError as e:
        raise UsageError(f"{e}; pick --cell-m in [1, 20]") from None


def _check(args) -> None:
    if getattr(args, "connect", None) is not None:
        raise UsageError("--mission formation flies the built-in vehicles only; drop --connect")
    if not (args.speedup == 0 or args.speedup >= 1):
        raise UsageError("--speedup must be 0 (as fast as possible) or >= 1")
    if args.sql_seed < 0:
        raise UsageError("--sql-seed must be >= 0")
    if not 0 <= args.sims <= args.agents:
        raise UsageError(
            f"--sims {args.sims}: give 1..{args.agents} processes (or 0: one per CPU core)"
        )
    if not 0 <= args.instance <= ports.MAX_INSTANCE - args.agents + 1:
        raise UsageError(
            f"--instance {args.instance} + {args.agents} vehicles goes past instance "
            f"{ports.MAX_INSTANCE}; pick a smaller --instance"
        )


def obtain_plan(args) -> tuple[list[list[tuple[int, int]]], dict]:
    """The lock-step plan (--policy-file, or learned: policy.sql.learn_plan) and where it came
    from (for config.json). UsageError if unusable."""
    from skyherd.policy.sql import GridParams, PlanParams, learn_plan
    from skyherd.policy.sql.layout import STARTS

    K = args.agents
    size = GridParams().size
    if args.policy_file:
        try:
            plan = load_plan(args.policy_file, K, size)
        except PlanError as e:
            raise UsageError(f"{e}; pass a plan_K{K}.json from `skyherd train sql`") from None
        return plan, {"source": "file", "path": str(args.policy_file)}
    if K not in STARTS:
        raise UsageError(f"the study's SQL-SIE plans are for K = {', '.join(map(str, STARTS))}: "
                         f"for K = {K} pass --policy-file")  # fmt: skip
    from tqdm import tqdm

    params = PlanParams(GridParams(n_agents=K), seed=args.sql_seed)
    try:
        with tqdm(total=params.hyper.episodes, desc=f"train SQL-SIE K={K}", unit="ep") as bar:
            paths = learn_plan(params, bar.update)
        plan = validate_plan(paths, K, size)
    except ValueError as e:
        raise UsageError(f"{e}; try another --sql-seed or pass --policy-file") from None
    return plan, params.describe()


def run_formation(args: argparse.Namespace) -> int:
    """Fly the formation as K simulators + one companion; 0 if every vehicle landed on its target."""
    from skyherd.scripts import launch
    from skyherd.scripts.fly import check_signing, per_run_key, signing_mode

    _check(args)
    _check_children(args)
    key = check_signing(args)
    params = _params(args)
    K = args.agents
    plan, plan_info = obtain_plan(args)
    instances = vehicle_instances(args.instance, K)
    _ports_free(instances)
    homes = vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)
    from skyherd.scripts import waysout

    folder = waysout.open_run_folder("fly", args.runs_dir)  # UsageError: not writable, full
    run_dir = folder.path
    key = key or per_run_key(args, run_dir)  # one key for every vehicle's two links
    signing = ["--signing-key", str(key)] if key is not None else []
    folder.write_config(
        {"args": args_dict(args), "mission": "formation", "formation": params,
         "plan": plan_info, "field_origin": DEFAULT_HOME, "homes": homes, "instances": instances,
         "frame": "field NED about field_origin; cell (x, y) centre at north (y-1)*cell_m, "
                  "east (x-1)*cell_m",
         "signing": signing_mode(args)}
    )  # fmt: skip
    atomic_write_text(run_dir / "plan.json", plan_text(plan))
    waysout.write_running(run_dir)
    print(f"skyherd fly: run folder {run_dir}", flush=True)
    skipped = (
        f" (10 skipped: its companion port is the ground stations' {GCS_REMOTE_PORT})"
        if 10 in range(instances[0], instances[-1])
        else ""
    )
    print(f"skyherd fly: {K} vehicles (instances {instances[0]}..{instances[-1]}{skipped}), plan of "
          f"{len(plan[0]) - 1} steps, speed-up {args.speedup:g}, lockstep", flush=True)  # fmt: skip
    groups = sim_groups(K, args.sims)
    print(f"skyherd fly: {len(groups)} simulator process{'es' if len(groups) > 1 else ''} "
          f"({', '.join(str(len(g)) for g in groups)} vehicles), logs sim<g>.log", flush=True)  # fmt: skip
    why = "interrupted (Ctrl-C)"
    kids = launch.Launch()
    try:
        with kids:  # stopped on every way out, the companion first
            for g, group in enumerate(groups):
                fleet = [FleetVehicle(f"uav{k}", instances[k], args.seed + k,
                                      (homes[k].lat_deg, homes[k].lon_deg, homes[k].alt_m)) for k in group]  # fmt: skip
                fleet_file = run_dir / f"sim{g}.json"
                write_fleet(fleet_file, fleet)
                kids.start_sim(f"sim{g}", launch.skyherd_cmd(
                    "sim", "--fleet", str(fleet_file), "--ugvs", "none", "--speedup", repr(args.speedup),
                    "--latency", repr(args.latency), "--run-dir", str(run_dir), *signing), run_dir / f"sim{g}.log")  # fmt: skip
            kids.start_companion(launch.skyherd_cmd(
                "companion", "--mission", "formation", "--plan", str(run_dir / "plan.json"), "--cell-m",
                repr(params.cell_m), "--instance", str(args.instance), "--run-dir", str(run_dir),
                *signing))  # fmt: skip
            rc, why = kids.supervise(args.timeout)
    except KeyboardInterrupt as e:  # SIGINT, SIGTERM, SIGHUP (scripts.launch): 128 + signum
        rc, why = waysout.interrupted(e)
    ok = waysout.report_safely(formation_report, run_dir, rc, why, why=why)  # never raises
    output = [ln for c in kids.sims for ln in (c.lines or ())]  # kept in memory
    waysout.append_ending(
        run_dir, waysout.ending_lines(run_dir, [f"uav{k}" for k in range(K)], output)
    )
    return 0 if ok and rc == 0 else (rc if rc > 128 else 1)


def _check_children(args) -> None:
    """The children's own checks on the options passed on to them (scripts.sim and
    scripts.companion `check_args`; the fleet and plan files are made later): UsageError."""
    from skyherd.scripts import companion, sim

    why = sim.check_args(["--ugvs", "none", "--speedup", repr(args.speedup), "--latency",
                          repr(args.latency), "--instance", str(args.instance)])  # fmt: skip
    why = why or companion.check_args(["--mission", "formation", "--plan", "plan.json",
                                       "--cell-m", repr(args.cell_m), "--instance", str(args.instance)])  # fmt: skip
    if why:
        raise UsageError(why)


def sim_groups(K: int, sims: int) -> list[list[int]]:
    """Vehicles 0..K-1 shared among `sims` processes (0: one per CPU core, at most K), in
    contiguous groups whose sizes differ by at most one."""
    n = sims if sims > 0 else max(1, min(K, os.cpu_count() or 1))
    base, extra = divmod(K, n)
    groups, k = [], 0
    for g in range(n):
        size = base + (1 if g < extra else 0)
        groups.append(list(range(k, k + size)))
        k += size
    return groups


def _ports_free(instances: list[int]) -> None:
    """UsageError before anything starts if a vehicle's or the companion's UDP port is taken."""
    taken = ports.taken_udp_port(instances)
    if taken is not None:
        inst, port, why = taken
        raise UsageError(f"UDP port {port} of instance {inst} is taken ({why}); "
                         "pick another --instance")  # fmt: skip


def _json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def formation_report(run_dir: Path, rc: int, why: str) -> bool:
    """summary.md and formation.png from the run folder; True if every vehicle landed on its
    target cell, passed every check of safety.judge, and the companion completed the mission."""
    from skyherd.policy.sql import GridParams, build_layout

    run_dir = Path(run_dir)
    cfg = _json(run_dir / "config.json")
    params = FormationParams(**{k: v for k, v in cfg.get("formation", {}).items()
                                if k in FormationParams.__dataclass_fields__})  # fmt: skip
    plan = [[tuple(c) for c in p] for p in json.loads((run_dir / "plan.json").read_text())]
    K = len(plan)
    comp = _json(run_dir / "companion.json")
    times = {k: (math.nan if v is None else v) for k, v in comp.get("times", {}).items()}
    t_plan = times.get("plan_start", math.nan)
    paths_ne = plan_ne(plan, params.cell_m)
    tracks = read_tracks(run_dir, K)
    instances = cfg.get("instances") or vehicle_instances(
        int(cfg.get("args", {}).get("instance", 0)), K
    )
    moves = plan_moves(plan)
    rows, land_err = [], []
    for k in range(K):
        tr = tracks[k]
        err = float(np.hypot(*(tr[-1, 1:3] - paths_ne[k, -1]))) if len(tr) else math.nan
        land_err.append(err)
        alt_end = round(-float(tr[-1, 3]), 3) + 0.0 if len(tr) else math.nan
        rows.append([instances[k], str(plan[k][0]), str(plan[k][-1]), params.altitude(k), moves[k],
                     *tracking_error(tr, paths_ne[k], t_plan, params.step_s), err, alt_end])  # fmt: skip
    table = markdown_table(
        ["instance", "start cell", "target cell", "cruise alt [m]", "moves",
         "tracking error max [m]", "RMS [m]", "landing error [m]", "final alt [m]"], rows)  # fmt: skip
    sep = separation(tracks, params.similar_alt_m)
    from skyherd.safety.judge import first_failed, verdict

    try:
        judged = judge_vehicles(run_dir, plan, params, comp)
    except (OSError, ValueError, KeyError, TypeError) as e:  # a run folder the judge cannot read
        judged = []
        why = f"{why}; not judged ({type(e).__name__}: {e})"
    verdicts = [verdict(c) for c in judged]
    ok = rc == 0 and comp.get("outcome") == "completed"
    landed = ok and all(e < params.cell_m / 2 for e in land_err)
    judged_ok = len(judged) == K and all(first_failed(c) is None for c in judged)
    bad = [f"uav{k}: {v}" for k, v in enumerate(verdicts) if v != "completed"]
    failed = ok and not judged_ok  # the mission completed, the judge says otherwise
    if failed:
        ok = landed = False
    stats = [_json(run_dir / f"uav{k}" / "sim_stats.json") for k in range(K)]
    # the flight: up to each simulator's last tick closed by the companion (world.sim)
    sim_s = min((s.get("flight_sim_s", math.nan) for s in stats), default=math.nan)
    wall_s = max((s.get("flight_wall_s", math.nan) for s in stats), default=math.nan)
    net = comp.get("net", {})
    summary_rows = [
        ["vehicles", K],
        [f"plan steps (one per {params.step_s:.3g} s)", len(plan[0]) - 1],
        ["landing error, largest [m]", max(land_err) if land_err else math.nan],
        ["landing error, mean [m]", float(np.mean(land_err)) if land_err else math.nan],
        ["all landed inside their target cell", landed],
        [f"min 3-D separation [m] (vehicles {sep.pair_3d[0]}, {sep.pair_3d[1]} at "
         f"t = {sep.t_3d:.1f} s)", sep.min_3d],
        [f"min horizontal separation, |Δalt| < {params.similar_alt_m:g} m [m]",
         sep.min_horizontal_similar_alt],
        ["min horizontal separation, any altitude [m]", sep.min_horizontal_any],
        ["decisions (every vehicle, every tick)", comp.get("decisions", 0)],
        ["safety-net switches / projected", f"{net.get('switches', 0)} / {net.get('projected', 0)}"],
        ["plan flight (sim) [s]", times.get("plan_end", math.nan) - t_plan],
        ["takeoff → all disarmed (sim) [s]",
         times.get("all_disarmed", math.nan) - times.get("takeoff", math.nan)],
        ["simulated [s] / wall [s]", f"{sim_s:.1f} / {wall_s:.1f}"],
        ["real-time factor sustained (sim / wall)", sim_s / wall_s if wall_s > 0 else math.nan],
        ["companion decision time p50 / p95 [ms]",
         f"{1e3 * (comp.get('decide_wall_p50_s') or math.nan):.2f} / "
         f"{1e3 * (comp.get('decide_wall_p95_s') or math.nan):.2f}"],
    ]  # fmt: skip
    overview = markdown_table(["metric", "value"], summary_rows)
    judge_rows = [[f"uav{k}", v, next((c.figure for c in judged[k] if c.name == "fence"), "")]
                  for k, v in enumerate(verdicts)]  # fmt: skip
    verdict_table = markdown_table(["vehicle", "judge (safety/judge.py)", "fence"], judge_rows)
    try:  # the learned plans' map (map seed 0); not drawn under a plan that ends elsewhere
        layout = build_layout(GridParams(n_agents=K))
        ends = sorted(layout.cell(*p[-1]) for p in plan)
        layout = layout if ends == sorted(int(s) for s in layout.targets) else None
    except ValueError:
        layout = None
    if any(len(t) for t in tracks):
        _plot(run_dir, params, plan, paths_ne, tracks, layout, sep)
    status = "completed" if ok else ("YIELDED" if comp.get("outcome") == "yielded" else "ABORTED")
    reason = flight_reason(comp.get("reason"), why)
    if failed:
        status, reason = "FAILED", "first failed check: " + ("; ".join(bad) or "not judged")
    atomic_write_text(run_dir / "summary.md",
        f"# skyherd fly: formation mission {status}\n\n"
        f"K = {K} quadrotors fly the learned lock-step grid plan ({params.cell_m:g} m cells, "
        f"{params.speed_mps:g} m/s, cruise at {params.altitude(0):g} + {params.altitude_step_m:g}·k m)"
        f" and land on their formation targets; {K} simulators and one companion in lockstep.\n"
        + (f"\n{'Ended' if ok else 'Aborted'}: {reason}\n" if reason and not ok else "")
        + (f"\nMAVLink signing: {cfg['signing']}.\n" if cfg.get("signing") else "")
        + f"\n{table}\n{overview}\n{verdict_table}"
    )  # fmt: skip
    print(table)
    print(overview)
    print(verdict_table)
    print(f"skyherd fly: formation {status}{': ' + reason if reason and not ok else ''}; "
          f"summary.md, formation.png, metrics.csv, decisions.jsonl in {run_dir}")  # fmt: skip
    return landed


def _plot(run_dir: Path, params, plan, paths_ne, tracks, layout, sep) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle

    c = params.cell_m
    fig = plt.figure(figsize=(15, 7))
    grid = fig.add_gridspec(2, 2, width_ratios=[1.25, 1])
    ax1 = fig.add_subplot(grid[:, 0])
    ax2 = fig.add_subplot(grid[0, 1])
    ax3 = fig.add_subplot(grid[1, 1])
    colors = plt.cm.tab20(np.linspace(0, 1, max(len(plan), 2)))
    if layout is not None:
        M = layout.size
        ax1.add_patch(Rectangle((-c / 2, -c / 2), M * c, M * c, fill=False, ec="0.6", lw=0.8))
        for s in np.flatnonzero(layout.obstacle):
            x, y = layout.xy(int(s))
            ax1.add_patch(Rectangle(((x - 1.5) * c, (y - 1.5) * c), c, c, color="0.3"))
        roi = np.flatnonzero(layout.roi_id >= 0)
        lo = min(layout.xy(int(s))[0] for s in roi)
        ax1.add_patch(Rectangle(((lo - 1.5) * c, (lo - 1.5) * c), (M - lo + 1) * c,
                                (M - lo + 1) * c, fill=False, ec="g", ls="--", lw=1))  # fmt: skip
    for k, tr in enumerate(tracks):
        col = colors[k]
        ax1.plot(paths_ne[k, :, 1], paths_ne[k, :, 0], ":", color=col, lw=0.8)
        if len(tr):
            ax1.plot(tr[:, 2], tr[:, 1], "-", color=col, lw=1.2, label=f"vehicle {k}")
            ax1.plot(tr[-1, 2], tr[-1, 1], "x", color=col, ms=7)
            ax2.plot(tr[:, 0], -tr[:, 3], "-", color=col, lw=1)
        ax1.plot(*paths_ne[k, 0, ::-1], "o", color=col, ms=4)
        ax1.add_patch(Rectangle((paths_ne[k, -1, 1] - c / 2, paths_ne[k, -1, 0] - c / 2), c, c,
                                fill=False, ec=col, lw=1.2))  # fmt: skip
    ax1.set_xlabel("east [m]")
    ax1.set_ylabel("north [m]")
    ax1.set_aspect("equal")
    ax1.set_title("tracks over the grid (o start, □ target cell, x landing; grey obstacles, "
                  "green ROI)", fontsize=9)  # fmt: skip
    if len(plan) <= 16:
        ax1.legend(fontsize=7, loc="lower right", ncol=2)
    ax2.set_ylabel("altitude above home [m]")
    ax2.set_title("altitude")
    if sep.times is not None:
        ax3.plot(sep.times, sep.series_3d, "k-", lw=1, label="closest pair, 3-D")
        ax3.plot(sep.times, sep.series_similar, "r-", lw=1,
                 label=f"closest pair within {params.similar_alt_m:g} m of altitude, horizontal")  # fmt: skip
        ax3.legend(fontsize=8)
    ax3.set_xlabel("simulation time [s]")
    ax3.set_ylabel("separation [m]")
    ax3.set_ylim(bottom=0)
    ax3.set_title("separation between vehicles")
    fig.tight_layout()
    fig.savefig(run_dir / "formation.png", dpi=110)
    plt.close(fig)
