"""Strömbom's shepherd (Strömbom et al. 2014), in metres: two sub-skills and the rule that
picks one.

  cohesion radius   f(N) = r_a · N^(2/3)
  collect           P_c = A_f + r_a · (A_f − Γ)/|A_f − Γ|       (A_f: the agent furthest from Γ)
  drive             P_d = Γ + r_a √N · (Γ − G)/|Γ − G|          (Γ: the flock's centre, G: goal)
  rule              drive when every agent is within f(N) of Γ, collect otherwise

The shepherd flies toward its point at `speed_mps` and stands while any agent is closer than
`stand_m` (3 r_a: it would scatter them). Everything here is a pure function of positions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.groundsim.flock import FlockParams, unit

COLLECT, DRIVE = "collect", "drive"
SKILLS = (COLLECT, DRIVE)


@dataclass(frozen=True)
class ShepherdParams:
    """The herding task: the goal region and the shepherd's own limits."""

    goal_ne: tuple[float, float] = (-25.0, 25.0)  # centre of the goal region [m]
    goal_radius_m: float = 8.0  # success: the flock's centre within this of goal_ne [m]
    speed_mps: float = 3.0  # shepherd speed (2 × the agents') [m/s]
    stand_factor: float = 3.0  # stand while an agent is within stand_factor · r_a [-]
    limit_s: float = 400.0  # an episode fails if the goal is not reached by then [s]
    decision_s: float = 0.5  # the shepherd chooses its point this often [s]

    def __post_init__(self) -> None:
        if not (self.goal_radius_m > 0 and self.speed_mps > 0 and self.limit_s > 0):
            raise ValueError("goal_radius_m, speed_mps and limit_s must be > 0")


def cohesion_radius(flock: FlockParams) -> float:
    """f(N) = r_a N^(2/3) [m]."""
    return flock.r_a_m * flock.n ** (2.0 / 3.0)


def furthest(pos: np.ndarray) -> tuple[int, float]:
    """(index, distance [m]) of the agent furthest from the flock's centre."""
    d = np.linalg.norm(pos - pos.mean(axis=0), axis=1)
    i = int(np.argmax(d))
    return i, float(d[i])


def collect_point(pos: np.ndarray, flock: FlockParams) -> np.ndarray:
    """P_c: r_a behind the furthest agent, on the side away from the centre."""
    i, _ = furthest(pos)
    return pos[i] + flock.r_a_m * unit(pos[i] - pos.mean(axis=0))


def drive_point(pos: np.ndarray, goal_ne, flock: FlockParams) -> np.ndarray:
    """P_d: r_a √N behind the flock's centre, on the side away from the goal."""
    g = pos.mean(axis=0)
    return g + flock.r_a_m * math.sqrt(flock.n) * unit(g - np.asarray(goal_ne, dtype=float))


def strombom_rule(pos: np.ndarray, flock: FlockParams) -> str:
    """DRIVE when every agent is within f(N) of the centre, else COLLECT."""
    return DRIVE if furthest(pos)[1] < cohesion_radius(flock) else COLLECT


def skill_point(skill: str, pos: np.ndarray, goal_ne, flock: FlockParams) -> np.ndarray:
    """The point (2,) [m] the chosen sub-skill flies to."""
    return drive_point(pos, goal_ne, flock) if skill == DRIVE else collect_point(pos, flock)


def shepherd_velocity(shepherd_ne, target_ne, pos: np.ndarray, flock: FlockParams,
                      p: ShepherdParams) -> np.ndarray:  # fmt: skip
    """The shepherd's horizontal velocity (2,) [m/s]: toward the target at speed_mps (slowing
    within 1 m of it), zero while an agent is within stand_factor · r_a."""
    s = np.asarray(shepherd_ne, dtype=float)
    if np.linalg.norm(pos - s, axis=1).min() < p.stand_factor * flock.r_a_m:
        return np.zeros(2)
    d = np.asarray(target_ne, dtype=float) - s
    return p.speed_mps * min(1.0, float(np.linalg.norm(d))) * unit(d)
