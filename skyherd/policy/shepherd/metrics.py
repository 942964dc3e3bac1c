"""Herding metrics of a flown run, from the simulator's truth (world.csv rows): success (the
flock's centre within the goal region), time to goal from the moment the flock started to move
(team_t = 0: the hand-over), and the flock's spread (mean distance from its centre) over time."""

from __future__ import annotations

import numpy as np

from skyherd.groundsim.flock import flock_spread
from skyherd.policy.shepherd.rules import ShepherdParams


def flock_track(rows: list[dict]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(team_t (T,) [s], UAV north/east (T, 2) [m], flock (T, N, 2) [m]) of the rows where the
    flock moves (team_t set)."""
    rows = [r for r in rows if str(r.get("team_t", "")).strip() != ""]
    n = sum(1 for k in (rows[0] if rows else {}) if k.startswith("ugv") and k.endswith("_n"))
    t = np.array([float(r["team_t"]) for r in rows])
    uav = np.array([[float(r["north"]), float(r["east"])] for r in rows]).reshape(-1, 2)
    flock = np.array([[[float(r[f"ugv{i}_n"]), float(r[f"ugv{i}_e"])] for i in range(n)]
                      for r in rows]).reshape(len(rows), n, 2)  # fmt: skip
    return t, uav, flock


def herding_metrics(rows: list[dict], task: ShepherdParams | None = None) -> dict:
    """success, time_to_goal_s (None: not reached), spread at start / end / max [m], the
    centre's distance to the goal at start and end [m], the flown time [s]."""
    task = task if task is not None else ShepherdParams()
    t, _, flock = flock_track(rows)
    if len(t) == 0 or flock.shape[1] == 0:
        return {"success": False, "time_to_goal_s": None, "samples": 0}
    goal = np.asarray(task.goal_ne)
    dist = np.linalg.norm(flock.mean(axis=1) - goal, axis=1)
    inside = np.flatnonzero(dist < task.goal_radius_m)
    spread = np.array([flock_spread(f) for f in flock])
    return {"success": bool(len(inside)), "time_to_goal_s": None if not len(inside) else round(float(t[inside[0]]), 3),
            "spread_start_m": round(float(spread[0]), 3), "spread_end_m": round(float(spread[-1]), 3),
            "spread_max_m": round(float(spread.max()), 3), "goal_distance_start_m": round(float(dist[0]), 3),
            "goal_distance_end_m": round(float(dist[-1]), 3), "flown_s": round(float(t[-1]), 3),
            "samples": len(t), "agents": int(flock.shape[1]),
            "goal_ne": list(task.goal_ne), "goal_radius_m": task.goal_radius_m}  # fmt: skip
