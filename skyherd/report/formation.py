"""`skyherd fly --mission formation`'s report: summary.md (each vehicle's tracking and landing,
the separations, the judge's verdict per vehicle) and formation.png, from the run folder the K
simulators and the companion wrote. matplotlib is imported inside the plot."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from skyherd.mission.formation_plan import (
    FormationParams,
    plan_moves,
    plan_ne,
    separation,
    tracking_error,
    vehicle_instances,
)
from skyherd.mission.formation_run import judge_vehicles, read_tracks
from skyherd.report.reason import flight_reason
from skyherd.runio.runfolder import atomic_write_text, markdown_table


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
        plot_formation(run_dir, params, plan, paths_ne, tracks, layout, sep)
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


def plot_formation(run_dir: Path, params, plan, paths_ne, tracks, layout, sep) -> None:
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
