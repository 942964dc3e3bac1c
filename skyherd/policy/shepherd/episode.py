"""One herding episode: the flock (groundsim.flock) and a point shepherd that flies the chosen
sub-skill's point at its speed (policy.shepherd.rules), on one clock. Seeded: the flock's start
and noise come from `seed` alone.

The shepherd starts at home (0, 0), where the UAV hands over in `skyherd fly --mission shepherd`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyherd.groundsim.flock import Flock, FlockParams, flock_spread
from skyherd.policy.shepherd.rules import DRIVE, ShepherdParams, shepherd_velocity, skill_point

DT_S = 0.1  # integration step of the episode [s] (the camera tick of the flown mission)


@dataclass
class Episode:
    """What one episode did: success, time to goal [s] (None: not reached), the spread
    (mean distance from the centre) [m] at the start and the end, the fraction of decisions
    that drove, and (with demos) the positions and choices at each decision."""

    seed: int
    success: bool
    time_to_goal_s: float | None
    spread_start_m: float
    spread_end_m: float
    drive_fraction: float
    track: list = field(default_factory=list)  # (t, shepherd n, e, centre n, e, spread)
    demo_positions: list = field(default_factory=list)
    demo_skills: list = field(default_factory=list)


def in_goal(pos: np.ndarray, task: ShepherdParams) -> bool:
    """Success: the flock's centre within goal_radius_m of the goal."""
    return float(np.linalg.norm(pos.mean(axis=0) - np.asarray(task.goal_ne))) < task.goal_radius_m


def run_episode(seed: int, selector, flock_p: FlockParams | None = None,
                task: ShepherdParams | None = None, demos: bool = False,
                keep_track: bool = False) -> Episode:  # fmt: skip
    """Herd the flock of `seed` with `selector` until the goal or task.limit_s (defaults:
    FlockParams(), ShepherdParams())."""
    flock_p = flock_p if flock_p is not None else FlockParams()
    task = task if task is not None else ShepherdParams()
    flock = Flock.start(flock_p, np.random.default_rng(seed))
    s = np.zeros(2)
    spread0 = flock_spread(flock.pos)
    t, t_dec, target, drives, decisions = 0.0, -1e9, s.copy(), 0, 0
    ep = Episode(seed, False, None, spread0, spread0, 0.0)
    n_steps = int(round(task.limit_s / DT_S))
    for k in range(n_steps):
        t = k * DT_S
        if in_goal(flock.pos, task):
            ep.success, ep.time_to_goal_s = True, round(t, 3)
            break
        if t - t_dec >= task.decision_s - 1e-9:
            t_dec = t
            skill, _ = selector.choose(flock.pos, task.goal_ne, flock_p)
            target = skill_point(skill, flock.pos, task.goal_ne, flock_p)
            drives += skill == DRIVE
            decisions += 1
            if demos:
                ep.demo_positions.append(flock.pos.copy())
                ep.demo_skills.append(skill)
        s = s + DT_S * shepherd_velocity(s, target, flock.pos, flock_p, task)
        flock.set_shepherd(s)
        flock.step(t, DT_S)
        if keep_track:
            c = flock.pos.mean(axis=0)
            ep.track.append((round(t + DT_S, 3), *s, *c, flock_spread(flock.pos)))
    ep.spread_end_m = flock_spread(flock.pos)
    ep.drive_fraction = drives / max(decisions, 1)
    return ep
