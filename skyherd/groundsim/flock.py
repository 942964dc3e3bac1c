"""A UGV flock that reacts to a shepherd (the UAV), after Strömbom et al. 2014, "Solving the
shepherding problem: heuristics for herding autonomous, interacting agents" (J. R. Soc.
Interface 11: 20140719), in metres and seconds.

Each agent i at A_i (north, east) [m] carries a heading vector H_i. Every `step_s` it chooses a
new heading from (docs/shepherding.md numbers the equations the same way):

  (1) shepherd repulsion  R^s_i = (A_i − S) / |A_i − S|               if |A_i − S| < r_s
  (2) local repulsion     R^a_i = Σ_{j: |A_i − A_j| < r_a} (A_i − A_j) / |A_i − A_j|
  (3) attraction          C_i   = LCM_i − A_i   (LCM: centre of the n nearest other agents)
  (4) new heading         H'_i  = h Ĥ_i + c Ĉ_i + ρ_a R̂^a_i + ρ_s R̂^s_i + e ε̂_i
  (5) motion              A_i  ← A_i + v Ĥ'_i dt   (continuous between two decisions)

(x̂ is x / |x|, or 0 for x = 0; ε̂ a random unit vector.) An agent that does not sense the
shepherd stands and grazes: it moves only to leave a neighbour closer than r_a (ρ_a R̂^a_i
alone) or, with probability `graze_p` per decision, one random heading (4 with h = c = ρ_s = 0).
The shepherd is felt by its horizontal position only. Randomness comes from the Generator
passed in; the flock keeps no global state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.groundsim.ugv import UGVStates


@dataclass(frozen=True)
class FlockParams:
    """The flock's behaviour (Strömbom et al. 2014, Table 1, scaled to metres: r_a = 2 m)."""

    n: int = 10  # agents (UGVs) [-]
    speed_mps: float = 1.5  # agent speed v while it moves [m/s]
    step_s: float = 0.5  # agents choose a new heading this often [s]
    r_a_m: float = 2.0  # agent-agent repulsion distance r_a [m]
    r_s_m: float = 30.0  # the shepherd is sensed within this horizontal distance r_s [m]
    neighbours: int = 6  # n: nearest other agents in the local centre of mass [-]
    h: float = 0.5  # inertia weight [-]
    c: float = 1.05  # attraction weight [-]
    rho_a: float = 2.0  # agent repulsion weight [-]
    rho_s: float = 1.0  # shepherd repulsion weight [-]
    e: float = 0.3  # noise weight [-]
    graze_p: float = 0.05  # chance per decision that an undisturbed agent takes a step [-]
    start_ne: tuple[float, float] = (30.0, -20.0)  # centre of the start square [m]
    start_half_m: float = 12.0  # agents start uniformly in a square of this half-side [m]

    def __post_init__(self) -> None:
        if self.n < 1 or self.neighbours < 0:
            raise ValueError(f"n must be >= 1 and neighbours >= 0, got {self.n}, {self.neighbours}")
        if not (self.speed_mps > 0 and self.step_s > 0 and self.r_a_m > 0 and self.r_s_m > 0):
            raise ValueError("speed_mps, step_s, r_a_m and r_s_m must be > 0")
        if not 0.0 <= self.graze_p <= 1.0:
            raise ValueError(f"graze_p must be in [0, 1], got {self.graze_p}")


def unit(x: np.ndarray) -> np.ndarray:
    """Rows of x (…, 2) scaled to length 1; zero rows stay zero."""
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x, dtype=float), where=n > 1e-12)


def new_headings(
    pos: np.ndarray, heading: np.ndarray, shepherd_ne, p: FlockParams, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """Eqs. (1)–(4) for all agents: (H' (N, 2), moving (N,) bool). Pure apart from `rng`.

    pos (N, 2) and heading (N, 2) north/east; shepherd_ne (2,) [m] or None (no shepherd)."""
    n = len(pos)
    d = pos[:, None, :] - pos[None, :, :]  # A_i − A_j, (N, N, 2)
    dist = np.linalg.norm(d, axis=-1)
    np.fill_diagonal(dist, np.inf)
    close = dist < p.r_a_m
    r_a = np.where(close[..., None], unit(d), 0.0).sum(axis=1)  # (2)
    if shepherd_ne is None:
        to_s = np.full((n, 2), np.inf)
        sensed = np.zeros(n, dtype=bool)
    else:
        to_s = pos - np.asarray(shepherd_ne, dtype=float)[None, :]
        sensed = np.linalg.norm(to_s, axis=1) < p.r_s_m
    r_s = np.where(sensed[:, None], unit(np.where(np.isfinite(to_s), to_s, 0.0)), 0.0)  # (1)
    k = min(p.neighbours, n - 1)
    if k > 0:
        nearest = np.argsort(dist, axis=1)[:, :k]
        c = pos[nearest].mean(axis=1) - pos  # (3)
    else:
        c = np.zeros((n, 2))
    ang = rng.uniform(-math.pi, math.pi, n)
    eps = np.c_[np.cos(ang), np.sin(ang)]
    herded = (p.h * unit(heading) + p.c * unit(c) + p.rho_a * unit(r_a)
              + p.rho_s * r_s + p.e * eps)  # (4)  # fmt: skip
    graze = rng.random(n) < p.graze_p
    grazing = np.where(graze[:, None], eps, p.rho_a * unit(r_a))
    h_new = np.where(sensed[:, None], herded, grazing)
    moving = sensed | graze | close.any(axis=1)
    return h_new, moving


class Flock:
    """N agents under eqs. (1)–(5). `step(t, dt)` on the shared simulation clock; the shepherd's
    horizontal position is set with `set_shepherd` before a step."""

    def __init__(self, pos_ne: np.ndarray, params: FlockParams, rng: np.random.Generator):
        self.p = params
        self.rng = rng
        self.pos = np.asarray(pos_ne, dtype=float).reshape(-1, 2).copy()
        if len(self.pos) != params.n:
            raise ValueError(f"{len(self.pos)} start positions for a flock of n={params.n}")
        self.heading = np.zeros_like(self.pos)  # H_i (unit or zero)
        self.moving = np.zeros(params.n, dtype=bool)
        self.shepherd_ne: np.ndarray | None = None
        self.t = 0.0
        self.t_next = 0.0  # the next decision instant [s]

    @classmethod
    def start(cls, params: FlockParams, rng: np.random.Generator) -> Flock:
        """Agents uniformly in the start square (drawn from `rng`)."""
        c, h = np.asarray(params.start_ne, dtype=float), params.start_half_m
        return cls(c + rng.uniform(-h, h, (params.n, 2)), params, rng)

    def set_shepherd(self, ne) -> None:
        self.shepherd_ne = None if ne is None else np.asarray(ne, dtype=float)[:2].copy()

    def step(self, t: float, dt: float) -> UGVStates:
        """Advance by dt [s]: decisions at every multiple of step_s, motion (5) in between."""
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        end = self.t + dt
        while self.t < end - 1e-12:
            if self.t >= self.t_next - 1e-9:
                h, self.moving = new_headings(
                    self.pos, self.heading, self.shepherd_ne, self.p, self.rng
                )
                self.heading = unit(h)
                self.t_next += self.p.step_s
            span = min(end, self.t_next) - self.t
            v = np.where(self.moving, self.p.speed_mps, 0.0)
            self.pos += (v * span)[:, None] * self.heading  # (5)
            self.t += span
        return self.states

    @property
    def states(self) -> UGVStates:
        """The agents as UGV states (heading from north, clockwise; speed v or 0)."""
        psi = np.arctan2(self.heading[:, 1], self.heading[:, 0])
        speed = np.where(self.moving, self.p.speed_mps, 0.0)
        return UGVStates(self.pos.copy(), psi, speed, np.zeros(self.p.n, dtype=bool))


def flock_centre(pos: np.ndarray) -> np.ndarray:
    """Global centre of mass (2,) [m]."""
    return np.asarray(pos, dtype=float).mean(axis=0)


def flock_spread(pos: np.ndarray) -> float:
    """Mean distance of the agents from their centre [m]."""
    pos = np.asarray(pos, dtype=float)
    return float(np.linalg.norm(pos - pos.mean(axis=0), axis=1).mean())


class FlockTeam:
    """The flock as a world's UGV team (the Formation interface of policy.groundair.scenarios:
    `step(dt)`, `positions()`, `detectable()`, `world.states`), plus `set_shepherd(ne)`: the
    world tells it where the UAV is before each step."""

    def __init__(self, rng: np.random.Generator, params: FlockParams | None = None):
        self.world = Flock.start(params if params is not None else FlockParams(), rng)
        self.t = 0.0

    def set_shepherd(self, ne) -> None:
        self.world.set_shepherd(ne)

    def step(self, dt: float) -> None:
        self.world.step(self.t, dt)
        self.t += dt

    def positions(self) -> list[tuple[float, float]]:
        return [(float(a), float(b)) for a, b in self.world.pos]

    def detectable(self) -> list[bool] | None:
        return None  # every marker shows
