"""The formation mission of `skyherd fly`: K quadrotors fly the learned SQL-SIE plan.

`skyherd fly --mission formation --agents K` takes the lock-step grid plan (trained in-process
with a fixed seed, a few seconds, or read from `--policy-file`, a `plan_K<K>.json` written by
`skyherd train sql`), maps the 50×50 grid onto the field (cell (x, y) → north (y−1)·cell,
east (x−1)·cell about the field origin), starts K built-in quadrotor SITL vehicles (instances
N..N+K−1, N = --instance, default 0) stepped in lockstep on one thread, and flies each through
its own MAVLink client to its formation target, landing there. The run folder gets the
tlog (every vehicle), metrics.csv (every position sample of every vehicle), formation.png,
the plan, and summary.md with landing errors, separations and times.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import asdict

import numpy as np

from flight.geo import DEFAULT_HOME
from hil.client import ClientTimeout, CommandError
from hil.formation import (
    TRACK_COLUMNS,
    FormationFlight,
    FormationParams,
    FormationVehicle,
    LockstepSwarm,
    PlanError,
    TrackRecorder,
    field_offsets,
    load_plan,
    open_clients,
    plan_moves,
    plan_ne,
    separation,
    tracking_error,
    validate_plan,
    vehicle_homes,
)
from hil.link import LinkError
from runio.runfolder import RunFolder, args_dict, atomic_write_text, markdown_table
from scripts.cli import UsageError
from scripts.fly_options import AGENT_CHOICES, add_formation_arguments  # noqa: F401 - the options live there

MAX_INSTANCE = 200  # EndpointConfig's limit


def _params(args) -> FormationParams:
    try:
        return FormationParams(cell_m=args.cell_m)
    except ValueError as e:
        raise UsageError(f"{e}; pick --cell-m in [1, 20]") from None


def _check(args) -> None:
    if getattr(args, "connect", None) is not None:
        raise UsageError("--mission formation flies the built-in vehicles only; drop --connect")
    if args.speedup < 1:
        raise UsageError("--speedup must be >= 1 for the built-in vehicles")
    if args.sql_seed < 0:
        raise UsageError("--sql-seed must be >= 0")
    if not 0 <= args.instance <= MAX_INSTANCE - args.agents + 1:
        raise UsageError(
            f"--instance {args.instance} + {args.agents} vehicles goes past instance "
            f"{MAX_INSTANCE}; pick a smaller --instance"
        )


def obtain_plan(args) -> tuple[list[list[tuple[int, int]]], dict]:
    """The lock-step plan and where it came from (for config.json). UsageError if unusable."""
    from policy.sql import Algorithm, GridParams, SQLHyper, build_layout, plan_paths, train

    K = args.agents
    size = GridParams().size
    if args.policy_file:
        try:
            plan = load_plan(args.policy_file, K, size)
        except PlanError as e:
            raise UsageError(f"{e}; pass a plan_K{K}.json from `skyherd train sql`") from None
        return plan, {"source": "file", "path": str(args.policy_file)}
    from tqdm import tqdm

    grid = GridParams(n_agents=K)
    hyper = SQLHyper()
    layout = build_layout(grid)
    with tqdm(total=hyper.episodes, desc=f"train SQL-SIE K={K}", unit="ep") as bar:
        res = train(Algorithm.SQL_SIE, layout, hyper, seed=args.sql_seed, progress=bar.update)
    try:
        plan = validate_plan([[list(c) for c in p] for p in plan_paths(res, K)], K, size)
    except ValueError as e:
        raise UsageError(f"{e}; try another --sql-seed or pass --policy-file") from None
    info = {"source": "trained", "algorithm": "sql-sie", "seed": args.sql_seed,
            "grid": asdict(grid), "hyper": asdict(hyper)}  # fmt: skip
    return plan, info


def run_formation(args: argparse.Namespace, run_dir: RunFolder) -> bool:
    """Fly the formation; True if every vehicle landed on its target cell."""
    _check(args)
    params = _params(args)
    K = args.agents
    plan, plan_info = obtain_plan(args)
    starts = [p[0] for p in plan]
    origin = DEFAULT_HOME  # the field origin: grid cell (1, 1)
    homes = vehicle_homes(origin, starts, params.cell_m)
    instances = [args.instance + k for k in range(K)]
    run_dir.write_config(
        {"args": args_dict(args), "mission": "formation", "formation": params,
         "plan": plan_info, "field_origin": origin, "homes": homes, "instances": instances,
         "frame": "field NED about field_origin; cell (x, y) centre at north (y-1)*cell_m, "
                  "east (x-1)*cell_m"}
    )  # fmt: skip
    atomic_write_text(run_dir.file("plan.json"), _plan_json(plan))
    try:
        swarm = LockstepSwarm(homes, args.instance, args.speedup, seed=args.seed)
    except OSError as e:
        raise UsageError(f"{e}; is another skyherd using instances {instances[0]}..{instances[-1]}? "
                         "pick another --instance") from None  # fmt: skip
    try:
        clients, tlog = open_clients(instances, run_dir.file("telemetry.tlog"))
    except LinkError as e:
        swarm.close()
        raise UsageError(f"{e}; pick another --instance") from None
    print(f"skyherd fly: {K} vehicles (instances {instances[0]}..{instances[-1]}), "
          f"plan of {len(plan[0]) - 1} steps, speed-up {args.speedup:g}")  # fmt: skip
    paths_ne = plan_ne(plan, params.cell_m)
    offsets = field_offsets(origin, homes)
    recorder = TrackRecorder(run_dir.metrics(TRACK_COLUMNS), K)
    vehicles = [
        FormationVehicle(k, c, offsets[k], params.altitude(k), paths_ne[k], params.step_s, recorder)
        for k, c in enumerate(clients)
    ]
    swarm.start()
    flight = FormationFlight(vehicles, params, args.timeout, swarm)
    ok, error = True, ""
    try:
        flight.fly()
    except (ClientTimeout, CommandError) as e:
        ok, error = False, str(e)
        if swarm.error and swarm.error not in error:
            error += f" ({swarm.error})"
        flight.bar.write(f"skyherd fly: {e}")
    finally:
        flight.close()
        times = flight.result_times()
        for c in clients:
            c.close()
        swarm.close()
        if tlog is not None:
            tlog.close()
    tracks = recorder.close()
    return _report(run_dir, args, params, plan, paths_ne, tracks, times, swarm, ok, error)


def _plan_json(plan) -> str:
    return (
        "[\n"
        + ",\n".join("  " + str([list(c) for c in p]).replace(" ", "") for p in plan)
        + "\n]\n"
    )


def _report(run_dir, args, params, plan, paths_ne, tracks, times, swarm, ok, error) -> bool:
    from policy.sql import GridParams, build_layout

    K = len(plan)
    moves = plan_moves(plan)
    rows, land_err = [], []
    for k in range(K):
        tr = tracks[k]
        target = paths_ne[k, -1]
        err = float(np.hypot(*(tr[-1, 1:3] - target))) if len(tr) else math.nan
        land_err.append(err)
        alt_end = round(-float(tr[-1, 3]), 3) + 0.0 if len(tr) else math.nan
        rows.append([args.instance + k, str(plan[k][0]), str(plan[k][-1]), params.altitude(k),
                     moves[k], *tracking_error(tr, paths_ne[k], times.plan_start, params.step_s),
                     err, alt_end])  # fmt: skip
    table = markdown_table(
        ["instance", "start cell", "target cell", "cruise alt [m]", "moves",
         "tracking error max [m]", "RMS [m]", "landing error [m]", "final alt [m]"], rows)  # fmt: skip
    sep = separation(tracks, params.similar_alt_m)
    landed = ok and all(e < params.cell_m / 2 for e in land_err)
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
        ["plan flight (sim) [s]", times.plan_end - times.plan_start],
        ["takeoff → all disarmed (sim) [s]", times.all_disarmed - times.takeoff],
        ["wall time [s]", times.wall_s],
        ["real-time factor sustained (sim / wall)", swarm.real_time_factor],
    ]  # fmt: skip
    overview = markdown_table(["metric", "value"], summary_rows)
    try:  # the learned plans' map (map seed 0); not drawn under a plan that ends elsewhere
        layout = build_layout(GridParams(n_agents=K))
        ends = sorted(layout.cell(*p[-1]) for p in plan)
        layout = layout if ends == sorted(int(s) for s in layout.targets) else None
    except ValueError:
        layout = None
    _plot(run_dir, params, plan, paths_ne, tracks, layout, sep)
    status = "completed" if ok else "ABORTED"
    run_dir.write_summary(
        f"# skyherd fly: formation mission {status}\n\n"
        f"K = {K} quadrotors fly the learned lock-step grid plan ({params.cell_m:g} m cells, "
        f"{params.speed_mps:g} m/s, cruise at {params.altitude(0):g} + {params.altitude_step_m:g}·k m)"
        f" and land on their formation targets.\n"
        + (f"\nAborted: {error}\n" if error else "")
        + f"\n{table}\n{overview}"
    )
    print(table)
    print(overview)
    print(f"skyherd fly: {status}; tlog, metrics.csv, formation.png, plan.json and summary.md "
          f"in {run_dir.path}")  # fmt: skip
    return landed


def _plot(run_dir: RunFolder, params, plan, paths_ne, tracks, layout, sep) -> None:
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
    fig.savefig(run_dir.file("formation.png"), dpi=110)
    plt.close(fig)
