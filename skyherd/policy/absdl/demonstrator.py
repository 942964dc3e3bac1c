"""The scripted PD demonstrator of continuous velocity commands, with human-like imperfection.

From the observation o (14,) alone (policy.groundair.env): the team's image offset (com_u − ½,
com_v − ½; +u east, +v south) times the ground footprint at the altitude φ gives the offset
[m]; the change of the offset since the last decision plus the UAV's own velocity gives the
team's velocity. The command tracks the team and closes the offset (P on the offset, the team
velocity fed forward):

    v_ne   = v_team_ne + kp_xy · offset_ne                 (lateral)
    v_down = −kp_z · h · (spread − target) / target         (climb / descend: the altitude
                                                              error the spread implies)

With a UGV out of view it climbs at `search_climb_mps`. Each sub-task's demonstrator commands
only its own axes (lateral: north/east; climb: up only; descend: down only), the composite all.
Imperfections (DemonstratorParams): white noise [m/s] per axis, a reaction delay of whole
decisions, and a per-episode gain error drawn from [1 − e, 1 + e]. The command is clipped to
the continuous limits (policy.absdl.env.velocity_limits).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from skyherd.policy.absdl.env import VelocityLimits, velocity_limits
from skyherd.policy.absdl.params import DemonstratorParams
from skyherd.task.params import TaskParams

SUBTASKS: tuple[str, ...] = ("lateral", "climb", "descend")
AXES: dict[str, tuple[bool, bool, bool]] = {
    "lateral": (True, True, False),
    "climb": (False, False, True),
    "descend": (False, False, True),
    "composite": (True, True, True),
}
"""The axes (north, east, down) each sub-task's demonstrator commands."""


def restrict(subtask: str, v_ned) -> np.ndarray:
    """The command (3,) NED with only the sub-task's manoeuvres: its AXES, and for climb only
    up (down ≤ 0), for descend only down (down ≥ 0)."""
    v = np.asarray(v_ned, float) * np.array(AXES[subtask], float)
    if subtask == "climb":
        v[2] = min(v[2], 0.0)
    elif subtask == "descend":
        v[2] = max(v[2], 0.0)
    return v


def pd_command(o, task: TaskParams, p: DemonstratorParams, gain: float = 1.0) -> np.ndarray:
    """The noise-free PD command (3,) NED [m/s] for observation o (all axes)."""
    cam = task.camera
    h = max(float(o[3]) * 60.0, 1.0)  # φ altitude = alt / 60 m (perception.features)
    w_m = 2.0 * h * math.tan(cam.hfov_rad / 2.0)  # ground footprint width [m]
    h_m = w_m * cam.height_px / cam.width_px
    u = task.uav
    vmax = (u.v_xy_mps, u.v_xy_mps, max(u.v_up_mps, u.v_down_mps))
    v_uav = [(float(o[8 + i]) - 0.5) * 2.0 * vmax[i] for i in range(3)]
    if o[4] <= 0.0:  # nothing in view: hold and climb to search
        return np.array([0.0, 0.0, -p.search_climb_mps])
    off_n, off_e = -(float(o[1]) - 0.5) * h_m, (float(o[0]) - 0.5) * w_m
    dn, de = -(float(o[12]) - 0.5) / 5.0 * h_m, (float(o[11]) - 0.5) / 5.0 * w_m
    team_n, team_e = v_uav[0] + dn / task.dt_s, v_uav[1] + de / task.dt_s
    vn = team_n + gain * p.kp_xy * off_n
    ve = team_e + gain * p.kp_xy * off_e
    if o[5] <= 0.5:  # someone out of view: widen the view first
        vd = -p.search_climb_mps
    else:
        vd = -gain * p.kp_z * h * (float(o[2]) - p.spread_target) / p.spread_target
    return np.array([vn, ve, vd])


class Demonstrator:
    """callable(obs) → (3,) NED command of one sub-task; `reset(rng)` draws an episode's error."""

    def __init__(
        self,
        subtask: str,
        params: DemonstratorParams,
        task: TaskParams | None = None,
        limits: VelocityLimits | None = None,
    ):
        if subtask not in AXES:
            raise ValueError(f"unknown sub-task {subtask!r}; choose from {', '.join(AXES)}")
        self.subtask = subtask
        self.p = params
        self.task = task or TaskParams()
        self.limits = limits or velocity_limits()
        self.mask = np.array(AXES[subtask], float)
        self.rng = np.random.default_rng(0)
        self.gain = 1.0
        self.queue: deque = deque()

    def reset(self, rng: np.random.Generator) -> None:
        self.rng = rng
        e = self.p.gain_error
        self.gain = float(rng.uniform(1.0 - e, 1.0 + e)) if e > 0 else 1.0
        self.queue.clear()

    def ideal(self, o) -> np.ndarray:
        """The noise-free, undelayed command of this sub-task (the DAgger label)."""
        return self.limits.clip(restrict(self.subtask, pd_command(o, self.task, self.p)))

    def __call__(self, o) -> np.ndarray:
        v = restrict(self.subtask, pd_command(o, self.task, self.p, self.gain))
        if self.p.noise_mps > 0:
            v = v + self.rng.normal(0.0, self.p.noise_mps, 3) * self.mask
        self.queue.append(v)
        v = self.queue[0] if len(self.queue) > self.p.delay_steps else np.zeros(3)
        while len(self.queue) > self.p.delay_steps:
            self.queue.popleft()
        return self.limits.clip(v)
