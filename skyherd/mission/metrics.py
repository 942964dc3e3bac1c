"""The missions' metrics, computed from what the run folder recorded (so `skyherd fly` can
judge a flight flown by two other processes): decisions.jsonl from the companion, world.csv
(the world's truth at each camera frame) from the simulator."""

from __future__ import annotations

import math

import numpy as np

from skyherd.mission.pilots import DESCENT_PILOT
from skyherd.task.fastphi import min_circle
from skyherd.task.params import TaskParams


def groundair_metrics(decisions: list[dict], world: list[dict], task: TaskParams) -> dict:
    """All-in-view fraction (φ's all-in-view flag over the pilot's decisions), the footprint over
    the team's smallest enclosing circle (true altitude and UGV positions at each decision, only
    where all UGVs are in view), and the number of times the team went out of view. The
    landing's descent behind the net (pilot DESCENT_PILOT) is not the mission's."""
    decisions = [d for d in decisions if d.get("pilot") != DESCENT_PILOT]  # the landing's
    cam = task.camera
    world_t = np.array([float(r["t"]) for r in world])
    in_view = np.array([bool(d["phi"]) and d["phi"][5] > 0.5 for d in decisions], dtype=bool)
    ratios = []
    for d, seen in zip(decisions, in_view):
        w = _nearest(world, world_t, float(d["t"]))
        if not seen or w is None:
            continue
        ugvs = [(float(w[f"ugv{i}_n"]), float(w[f"ugv{i}_e"])) for i in range(task.n_ugvs)]
        r = min_circle(ugvs)[2]
        z = -float(w["down"]) - cam.mount_offset_frd[2]
        footprint = (cam.width_px * z / cam.fx) * (cam.height_px * z / cam.fx)
        ratios.append(footprint / max(math.pi * r * r, 1e-6))
    losses = int(np.sum(in_view[:-1] & ~in_view[1:])) if len(in_view) > 1 else 0
    return {
        "decisions": len(decisions),
        "in_view": float(in_view.mean()) if len(in_view) else None,
        "footprint_ratio": float(np.mean(ratios)) if ratios else None,
        "losses": losses,
        "verdicts": {
            v: sum(1 for d in decisions if d["verdict"] == v)
            for v in ("accepted", "projected", "fallback", "pid")
        },  # fmt: skip
    }


def _nearest(rows: list[dict], ts: np.ndarray, t: float, tol_s: float = 0.06) -> dict | None:
    """The world row at time t (the same camera instant in lockstep; the nearest within `tol_s`
    when the world follows an outside vehicle's clock)."""
    if len(ts) == 0:
        return None
    i = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
    j = i - 1 if i > 0 and abs(ts[i - 1] - t) <= abs(ts[i] - t) else i
    return rows[j] if abs(ts[j] - t) <= tol_s else None


def cross_track(pos: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    """Largest horizontal distance [m] of the samples `pos` (K, ≥2) from the segment a→b."""
    if len(pos) == 0:
        return math.nan
    sel = pos[:, :2]
    ab = (b - a)[:2]
    u = np.clip(((sel - a[:2]) @ ab) / max(ab @ ab, 1e-9), 0.0, 1.0)
    closest = a[:2] + u[:, None] * ab
    return float(np.max(np.linalg.norm(sel - closest, axis=1)))
