"""UGV team behaviours of the seed's four scenarios, each needing one manoeuvre of the UAV.

The team is a formation: UGV i sits at centre c(t) + R(t)·ρ_i·(cos(θ(t) + α_i), sin(θ(t) + α_i))
(north, east) [m], α_i = 2πi/n + jitter, ρ_i ∈ [0.75, 1]. The centre drives with speed s and a
heading that weaves, ψ(t) = ψ₀ + A·sin(ω t + φ). The scenarios differ in what moves:

====================  ==========================================  ===========================
scenario              UGV behaviour                               manoeuvre it needs
====================  ==========================================  ===========================
1 lateral             convoy drives and turns, spread constant    ±north/±east, fixed altitude
2 climb               convoy parked, spreads out (R grows)        climb only
3 descend             convoy parked, closes in (R shrinks)        descend only
4 composite           convoy drives, turns and breathes (R ± A)   all of them
====================  ==========================================  ===========================

All randomness is drawn at `reset` from the generator passed in; stepping is deterministic.

`groundsim:<behaviour>` scenarios (GROUNDSIM_SCENARIOS) drive the UGVs with the ground world's
kinematic unicycle model and scripted behaviours instead (groundsim.kinematic, route, convoy,
random walk, stop-and-go, speed-off, camouflage): used to test learned policies on UGV motion
they were not trained on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SCENARIOS: tuple[str, ...] = ("lateral", "climb", "descend", "composite")
SCENARIO_INDEX = {"lateral": 1, "climb": 2, "descend": 3, "composite": 4}
GROUNDSIM_SCENARIOS: tuple[str, ...] = tuple(
    f"groundsim:{b}" for b in ("route", "convoy", "random", "stopgo", "speedoff", "camouflage")
)
FLOCK = "flock"  # groundsim.flock: a flock that flees the UAV (`skyherd fly --mission shepherd`)
TEAMS: tuple[str, ...] = SCENARIOS + GROUNDSIM_SCENARIOS + (FLOCK,)  # every --ugvs team


@dataclass(frozen=True)
class FormationPlan:
    """Random draw of one episode's UGV behaviour (all SI: m, s, rad)."""

    speed: float  # centre speed [m/s]
    heading0: float  # initial heading [rad], 0 = north
    weave_amp: float  # heading weave amplitude A [rad]
    weave_w: float  # weave angular frequency ω [rad/s]
    weave_phase: float  # φ [rad]
    r0: float  # spread radius at t = 0 [m]
    r_rate: float  # linear spread change [m/s] (climb / descend)
    r_amp: float  # spread oscillation amplitude [m] (composite)
    r_w: float  # spread oscillation angular frequency [rad/s]
    r_phase: float  # [rad]
    spin: float  # formation rotation rate [rad/s]
    angles: tuple[float, ...]  # α_i [rad]
    radii: tuple[float, ...]  # ρ_i [-]
    r_min: float = 3.0  # spread floor [m]
    r_max: float = 20.0  # spread ceiling [m]

    def radius(self, t: float) -> float:
        r = self.r0 + self.r_rate * t + self.r_amp * math.sin(self.r_w * t + self.r_phase)
        return min(max(r, self.r_min), self.r_max)


def draw_plan(scenario: str, rng: np.random.Generator, n_ugvs: int = 3) -> FormationPlan:
    """Draw an episode's formation behaviour for a scenario."""
    if scenario not in SCENARIOS:
        raise ValueError(f"unknown scenario {scenario!r}; choose from {', '.join(SCENARIOS)}")
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    angles = tuple(2 * math.pi * i / n_ugvs + u(-0.3, 0.3) for i in range(n_ugvs))
    radii = tuple(u(0.75, 1.0) for _ in range(n_ugvs))
    common = dict(
        heading0=u(-math.pi, math.pi),
        weave_amp=u(0.5, 1.5),
        weave_w=u(0.1, 0.25),
        weave_phase=u(-math.pi, math.pi),
        spin=u(-0.05, 0.05),
        angles=angles,
        radii=radii,
    )
    if scenario == "lateral":
        return FormationPlan(
            speed=u(1.5, 3.0),
            r0=u(6.0, 10.0),
            r_rate=0.0,
            r_amp=0.0,
            r_w=0.0,
            r_phase=0.0,
            **common,
        )
    if scenario == "climb":
        return FormationPlan(
            speed=0.0,
            r0=u(4.0, 6.0),
            r_rate=u(0.12, 0.2),
            r_amp=0.0,
            r_w=0.0,
            r_phase=0.0,
            **common,
        )
    if scenario == "descend":
        return FormationPlan(
            speed=0.0,
            r0=u(14.0, 18.0),
            r_rate=-u(0.12, 0.2),
            r_amp=0.0,
            r_w=0.0,
            r_phase=0.0,
            **common,
        )
    return FormationPlan(
        speed=u(1.0, 2.5),
        r0=u(8.0, 10.0),
        r_rate=0.0,
        r_amp=u(3.0, 5.0),
        r_w=2 * math.pi / u(30.0, 45.0),
        r_phase=u(-math.pi, math.pi),
        **common,
    )


class Formation:
    """The UGV team's state; `step(dt)` moves it, `positions()` gives (north, east) [m] per UGV."""

    def __init__(self, plan: FormationPlan):
        self.plan = plan
        self.t = 0.0
        self.cn = 0.0
        self.ce = 0.0
        self.theta = 0.0

    def step(self, dt: float) -> None:
        p = self.plan
        # midpoint heading for the centre's motion over [t, t + dt]
        psi = p.heading0 + p.weave_amp * math.sin(p.weave_w * (self.t + 0.5 * dt) + p.weave_phase)
        self.cn += p.speed * math.cos(psi) * dt
        self.ce += p.speed * math.sin(psi) * dt
        self.theta += p.spin * dt
        self.t += dt

    @property
    def centre_velocity(self) -> tuple[float, float]:
        p = self.plan
        psi = p.heading0 + p.weave_amp * math.sin(p.weave_w * self.t + p.weave_phase)
        return p.speed * math.cos(psi), p.speed * math.sin(psi)

    def detectable(self) -> list[bool] | None:
        return None  # every UGV's marker is visible

    def positions(self) -> list[tuple[float, float]]:
        p = self.plan
        r = p.radius(self.t)
        return [
            (
                self.cn + r * rho * math.cos(self.theta + a),
                self.ce + r * rho * math.sin(self.theta + a),
            )
            for a, rho in zip(p.angles, p.radii)
        ]


class GroundsimTeam:
    """UGVs of groundsim's KinematicWorld behind the Formation interface (t, step, positions)."""

    def __init__(self, behaviour: str, rng: np.random.Generator, n_ugvs: int = 3):
        from skyherd.groundsim.behaviours import DriveParams, make_behaviour, triangle_offsets
        from skyherd.groundsim.kinematic import KinematicWorld
        from skyherd.groundsim.ugv import UGVStates

        params = DriveParams()
        states = UGVStates(triangle_offsets(n_ugvs), np.zeros(n_ugvs), np.zeros(n_ugvs))
        self.world = KinematicWorld(states, make_behaviour(behaviour, n_ugvs, rng, params), params)
        self.t = 0.0

    def step(self, dt: float) -> None:
        self.world.step(self.t, dt)
        self.t += dt

    def positions(self) -> list[tuple[float, float]]:
        return [(float(a), float(b)) for a, b in self.world.states.pos_ne]

    def detectable(self) -> list[bool] | None:
        camo = getattr(self.world.states, "camouflaged", None)
        return None if camo is None else [not bool(c) for c in camo]


def make_team(scenario: str, rng: np.random.Generator, n_ugvs: int = 3):
    """The UGV team of a scenario: a Formation, a GroundsimTeam for 'groundsim:<behaviour>', or
    the shepherding flock for 'flock' (its own size, groundsim.flock.FlockParams.n)."""
    if scenario == FLOCK:
        from skyherd.groundsim.flock import FlockTeam

        return FlockTeam(rng)
    if scenario in GROUNDSIM_SCENARIOS:
        return GroundsimTeam(scenario.split(":", 1)[1], rng, n_ugvs)
    return Formation(draw_plan(scenario, rng, n_ugvs))
