"""Scripted UGV behaviours: state and time → unicycle command (v [m/s], ω [rad/s]).

Backend-independent (numpy only): the kinematic world, the PyBullet world and the fast
training environment all drive their UGVs with these. Vectorised over the N UGVs.

Unicycle / differential drive in NED: ṅ = v cos ψ, ė = v sin ψ, ψ̇ = ω, with ψ from north,
clockwise (ω > 0 turns right). A differential drive with track b turns (v, ω) into wheel
speeds v_left = v + ω b/2, v_right = v − ω b/2 (`wheel_speeds`).

Every behaviour has `command(t, states) -> UGVCommand`. Behaviours may keep their own progress
(waypoint index, random goals), never global state; randomness comes from a Generator passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from skyherd.groundsim.ugv import UGVStates


@dataclass(frozen=True)
class DriveParams:
    """Limits and gains of the go-to-point controller (one set for every UGV)."""

    v_cruise: float = 2.0  # route speed [m/s]
    v_max: float = 8.0  # hard speed limit [m/s]
    omega_max: float = 1.2  # turn-rate limit [rad/s]
    accel_max: float = 2.0  # speed change limit [m/s^2] (applied by the worlds)
    k_heading: float = 2.0  # heading gain [1/s]
    arrive_m: float = 1.0  # a waypoint counts as reached within this distance [m]


@dataclass(frozen=True)
class UGVCommand:
    """Commands for N UGVs: v (N,) [m/s], omega (N,) [rad/s], camouflaged (N,) bool."""

    v: np.ndarray
    omega: np.ndarray
    camouflaged: np.ndarray


class Behaviour(Protocol):
    def command(self, t: float, states: UGVStates) -> UGVCommand: ...


def wrap_pi(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return (a + np.pi) % (2.0 * np.pi) - np.pi


def go_to(
    states: UGVStates, goals_ne: np.ndarray, speed: np.ndarray | float, p: DriveParams
) -> tuple[np.ndarray, np.ndarray]:
    """Unicycle go-to-point law for all UGVs.

    ω = k_ψ · wrap(atan2(Δe, Δn) − ψ), clipped to ±ω_max; v = speed · max(cos(heading error), 0),
    slowed to d·k_ψ/2 near the goal so it arrives without orbiting. Returns (v (N,), ω (N,)).
    """
    d = goals_ne - states.pos_ne
    dist = np.hypot(d[:, 0], d[:, 1])
    err = wrap_pi(np.arctan2(d[:, 1], d[:, 0]) - states.heading)
    omega = np.clip(p.k_heading * err, -p.omega_max, p.omega_max)
    v = np.minimum(np.broadcast_to(speed, dist.shape), 0.5 * p.k_heading * dist)
    v = np.clip(v * np.maximum(np.cos(err), 0.0), 0.0, p.v_max)
    return v, omega


def wheel_speeds(v: np.ndarray, omega: np.ndarray, track_m: float) -> tuple:
    """Differential drive: (v, ω NED, clockwise) → (left, right) wheel rim speeds [m/s]."""
    return v + 0.5 * track_m * omega, v - 0.5 * track_m * omega


def _no_camo(n: int) -> np.ndarray:
    return np.zeros(n, dtype=bool)


class WaypointRoute:
    """The group drives a route in formation: UGV i aims at route waypoint + offsets[i].

    waypoints (M, 2) north/east [m]; offsets (N, 2) [m] formation offsets; each UGV moves to its
    next waypoint when within `arrive_m`; at the end it stops (or loops when `loop`).
    """

    def __init__(
        self,
        waypoints: np.ndarray,
        offsets: np.ndarray,
        params: DriveParams = DriveParams(),
        loop: bool = False,
    ):
        self.wp = np.asarray(waypoints, dtype=float).reshape(-1, 2)
        self.offsets = np.asarray(offsets, dtype=float).reshape(-1, 2)
        self.p = params
        self.loop = loop
        self.index = np.zeros(len(self.offsets), dtype=int)

    def goals(self) -> np.ndarray:
        return self.wp[self.index] + self.offsets

    def done(self) -> np.ndarray:
        """(N,) bool: UGV finished the route (never when looping)."""
        if self.loop:
            return np.zeros(len(self.index), dtype=bool)
        return self.index >= len(self.wp) - 1

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        goals = self.goals()
        reached = np.hypot(*(goals - states.pos_ne).T) < self.p.arrive_m
        last = self.index >= len(self.wp) - 1
        adv = reached & (~last | self.loop)
        self.index = np.where(adv, (self.index + 1) % len(self.wp), self.index)
        v, w = go_to(states, self.goals(), self.p.v_cruise, self.p)
        stop = reached & last & (not self.loop)
        v = np.where(stop, 0.0, v)
        w = np.where(stop, 0.0, w)
        return UGVCommand(v, w, _no_camo(states.n))


class Convoy:
    """UGV 0 drives the route; UGV i follows UGV i−1 at `spacing_m`.

    A follower aims at its leader's position and sets v = k_gap·(distance − spacing), clipped
    to [0, v_max], so the gap closes to `spacing_m` at the leader's speed.
    """

    def __init__(
        self,
        waypoints: np.ndarray,
        spacing_m: float = 4.0,
        params: DriveParams = DriveParams(),
        k_gap: float = 1.0,
        loop: bool = True,
    ):
        self.lead = WaypointRoute(waypoints, np.zeros((1, 2)), params, loop)
        self.spacing = spacing_m
        self.k_gap = k_gap
        self.p = params

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        lead_state = UGVStates(states.pos_ne[:1], states.heading[:1], states.speed[:1])
        lc = self.lead.command(t, lead_state)
        goals = states.pos_ne[:-1]  # each follower aims at the one ahead
        fol = UGVStates(states.pos_ne[1:], states.heading[1:], states.speed[1:])
        gap = np.hypot(*(goals - fol.pos_ne).T)
        speed = np.clip(self.k_gap * (gap - self.spacing), 0.0, self.p.v_max)
        v, w = go_to(fol, goals, speed, self.p)
        v = np.where(gap > self.spacing, v, 0.0)
        return UGVCommand(
            np.concatenate([lc.v, v]), np.concatenate([lc.omega, w]), _no_camo(states.n)
        )


class RandomWalk:
    """Each UGV drives to a random goal in the area, then draws a new one.

    area (n_min, n_max, e_min, e_max) [m]; goals drawn from `rng` (a seeded Generator).
    """

    def __init__(
        self,
        area: tuple[float, float, float, float],
        n: int,
        rng: np.random.Generator,
        params: DriveParams = DriveParams(),
    ):
        self.area = area
        self.rng = rng
        self.p = params
        self.goal = self._draw(n)

    def _draw(self, k: int) -> np.ndarray:
        n0, n1, e0, e1 = self.area
        return np.c_[self.rng.uniform(n0, n1, k), self.rng.uniform(e0, e1, k)]

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        reached = np.hypot(*(self.goal - states.pos_ne).T) < self.p.arrive_m
        if reached.any():
            self.goal[reached] = self._draw(int(reached.sum()))
        v, w = go_to(states, self.goal, self.p.v_cruise, self.p)
        return UGVCommand(v, w, _no_camo(states.n))


class StopAndGo:
    """Wraps a behaviour: drive for `go_s`, stand still for `stop_s`, repeat (all UGVs)."""

    def __init__(self, inner: Behaviour, go_s: float = 8.0, stop_s: float = 4.0):
        self.inner, self.go_s, self.stop_s = inner, go_s, stop_s

    def moving(self, t: float) -> bool:
        return (t % (self.go_s + self.stop_s)) < self.go_s

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        c = self.inner.command(t, states)
        if self.moving(t):
            return c
        z = np.zeros(states.n)
        return UGVCommand(z, z.copy(), c.camouflaged)


class SpeedOff:
    """Wraps a behaviour: from `t_start` UGV `ugv` drives straight at `speed` (escapes the group).

    Heading is held at the one it had at `t_start` (`bearing_rad` overrides it).
    """

    def __init__(
        self,
        inner: Behaviour,
        ugv: int,
        t_start: float,
        speed: float = 6.0,
        bearing_rad: float | None = None,
        params: DriveParams = DriveParams(),
    ):
        self.inner, self.ugv, self.t_start, self.speed = inner, ugv, t_start, speed
        self.bearing = bearing_rad
        self.p = params

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        c = self.inner.command(t, states)
        if t < self.t_start:
            return c
        if self.bearing is None:
            self.bearing = float(states.heading[self.ugv])
        v, w = c.v.copy(), c.omega.copy()
        err = float(wrap_pi(np.array(self.bearing - states.heading[self.ugv])))
        v[self.ugv] = min(self.speed, self.p.v_max) * max(math.cos(err), 0.0)
        w[self.ugv] = float(np.clip(self.p.k_heading * err, -self.p.omega_max, self.p.omega_max))
        return UGVCommand(v, w, c.camouflaged)


class Camouflage:
    """Wraps a behaviour: UGV `ugv`'s marker takes the ground's colour in [t_start, t_end)."""

    def __init__(self, inner: Behaviour, ugv: int, t_start: float, t_end: float = math.inf):
        self.inner, self.ugv, self.t_start, self.t_end = inner, ugv, t_start, t_end

    def command(self, t: float, states: UGVStates) -> UGVCommand:
        c = self.inner.command(t, states)
        camo = c.camouflaged.copy()
        camo[self.ugv] |= self.t_start <= t < self.t_end
        return UGVCommand(c.v, c.omega, camo)


def triangle_offsets(n: int, radius_m: float = 3.0) -> np.ndarray:
    """Formation offsets (n, 2) [m] evenly on a circle (a triangle for 3 UGVs)."""
    a = 2 * np.pi * np.arange(n) / max(n, 1)
    return radius_m * np.c_[np.cos(a), np.sin(a)]


def make_behaviour(
    name: str, n: int, rng: np.random.Generator, params: DriveParams = DriveParams()
) -> Behaviour:
    """A named scenario: route, convoy, random, stopgo, speedoff, camouflage."""
    route = np.array([[0.0, 0.0], [40.0, 0.0], [40.0, 40.0], [0.0, 40.0]])
    base = WaypointRoute(route, triangle_offsets(n), params, loop=True)
    if name == "route":
        return base
    if name == "convoy":
        return Convoy(route, 4.0, params)
    if name == "random":
        return RandomWalk((-15.0, 15.0, -15.0, 15.0), n, rng, params)
    if name == "stopgo":
        return StopAndGo(base)
    if name == "speedoff":
        return SpeedOff(base, n - 1, 20.0, 6.0, params=params)
    if name == "camouflage":
        return Camouflage(base, n - 1, 15.0, 30.0)
    raise ValueError(
        f"unknown behaviour {name!r}: use route, convoy, random, stopgo, speedoff, camouflage"
    )


BEHAVIOURS = ("route", "convoy", "random", "stopgo", "speedoff", "camouflage")
