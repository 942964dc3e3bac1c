"""The UGV team in the world: a training scenario's formation or a groundsim behaviour, as
groundsim states, and the altitude that frames it at the start."""

from __future__ import annotations

import math

import numpy as np

from skyherd.groundsim.ugv import UGVStates
from skyherd.task.fastphi import min_circle
from skyherd.task.params import TaskParams
from skyherd.task.scenarios import make_team


def new_team(scenario: str, seed: int, n_ugvs: int):
    """The team of `scenario` drawn from `seed` (the same team wherever it is drawn)."""
    return make_team(scenario, np.random.default_rng(seed), n_ugvs)


def team_states(team) -> UGVStates:
    """The team's UGVs as groundsim states: a groundsim world's own states (headings,
    camouflage), or a Formation's (heading along the team's motion)."""
    if hasattr(team, "world"):
        return team.world.states
    pos = np.array(team.positions(), dtype=float)
    vn, ve = team.centre_velocity
    n = len(pos)
    return UGVStates(
        pos_ne=pos,
        heading=np.full(n, math.atan2(ve, vn)),
        speed=np.full(n, math.hypot(vn, ve)),
        camouflaged=np.zeros(n, dtype=bool),
    )


def start_altitude(task: TaskParams, team) -> float:
    """The altitude [m] that frames the team at the expert's spread target (as the env starts)."""
    cam = task.camera
    half_diag = 0.5 * math.hypot(cam.width_px, cam.height_px)
    radius = max(min_circle(team.positions())[2], 3.0)
    alt = cam.fx * radius / (task.spread_target * half_diag)
    alt += cam.mount_offset_frd[2]
    return float(min(max(alt, task.uav.alt_min_m + 2.0), task.uav.alt_max_m - 2.0))


def ugv_columns(n_ugvs: int) -> list[str]:
    """world.csv's UGV columns: ugv<i>_n, ugv<i>_e [m]."""
    return [f"ugv{i}_{ax}" for i in range(n_ugvs) for ax in ("n", "e")]
