"""Pilots: one interface, an observation in, a proposed `Setpoint` out.

    class Pilot(Protocol):
        name: str
        def propose(self, obs: Observation) -> Proposal

A pilot proposes; the safety net certifies (safety.supervisor); the mission layer maps the net's
verdict onto autopilot modes (mission.authority). Pilots never talk MAVLink and never read a
clock: the observation carries the tick's time.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.state import VehicleState
from skyherd.task.params import TaskParams, action_velocity_ned


@dataclass(frozen=True)
class Observation:
    """What a pilot may use at one decision: the tick time [s], the vehicle's state (its own
    estimate, from telemetry), φ(s) (8,) from the last camera frame, the policy observation
    (14,) built the training environment's way, and the decision period [s]."""

    t: float
    state: VehicleState
    phi: np.ndarray
    obs: np.ndarray
    dt_s: float


@dataclass(frozen=True)
class Proposal:
    setpoint: Setpoint | None  # None: no action this decision (a stalled AI)
    action: int = -1  # the discrete action of a learned policy (-1: none)
    explanation: dict | None = None  # a modular policy's reason (module, reason, concepts)


class Pilot(Protocol):
    name: str

    def propose(self, o: Observation) -> Proposal: ...


@dataclass
class PolicyPilot:
    """A learned policy: observation → discrete action → NED velocity, exactly as in training.
    A continuous policy (`policy.continuous`, policy.absdl) gives the NED velocity [m/s] itself;
    its explanation names the sub-skill network that decided and its weight."""

    policy: Callable[[np.ndarray], int]
    task: TaskParams
    yaw: float = 0.0  # the policy was trained heading north [rad]
    name: str = "policy"

    def propose(self, o: Observation) -> Proposal:
        if getattr(self.policy, "continuous", False):
            why = self.policy.explain(o.obs)
            vel = np.array(why["command_ned_mps"], dtype=float)
            return Proposal(Setpoint(vel_ned=vel, yaw=self.yaw), -1, why)
        a = int(self.policy(o.obs))
        explain = getattr(self.policy, "explain", None)
        why = explain(o.obs) if callable(explain) else None
        vel = np.array(action_velocity_ned(a, self.task.uav))
        return Proposal(Setpoint(vel_ned=vel, yaw=self.yaw), a, why)


@dataclass(frozen=True)
class FollowerGains:
    """PID follower on image features (φ entries are normalised to [0, 1])."""

    kp_xy: float = 12.0  # [m/s] per unit of centre-of-mass offset (0.5 = image edge)
    ki_xy: float = 1.0  # [m/s per s] per unit offset
    kd_xy: float = 4.0  # [m/s] per unit offset change per s
    kp_z: float = 10.0  # [m/s] per unit of spread error (climb when the team spreads)
    search_climb_mps: float = 1.0  # climb to widen the view while no UGV is seen [m/s]


@dataclass
class PerceptionFollower:
    """The classic pilot: centre the UGVs' centre of mass and hold the spread at the target.

    Image right is east and image up is north (level camera, heading north), so
        v_east = PID(com_u − ½),  v_north = −PID(com_v − ½),  v_down = −kp_z·(spread − target),
    each clipped to the policy's own speed commands. With no UGV in view it climbs to search.
    """

    task: TaskParams
    gains: FollowerGains = field(default_factory=FollowerGains)
    yaw: float = 0.0
    name: str = "pid"
    integral: np.ndarray = field(default_factory=lambda: np.zeros(2))
    prev: np.ndarray | None = None

    def propose(self, o: Observation) -> Proposal:
        u, g, phi, dt = self.task.uav, self.gains, o.phi, o.dt_s
        if phi[4] <= 0.0:  # nothing seen: hold position, climb to search
            self.integral[:] = 0.0
            self.prev = None
            return Proposal(
                Setpoint(
                    vel_ned=np.array([0.0, 0.0, -min(g.search_climb_mps, u.v_up_mps)]), yaw=self.yaw
                )
            )
        e = np.array([phi[0] - 0.5, phi[1] - 0.5])  # (right, down) in the image
        self.integral = np.clip(self.integral + e * dt, -2.0, 2.0)
        de = np.zeros(2) if self.prev is None or dt <= 0 else (e - self.prev) / dt
        self.prev = e
        right, down = g.kp_xy * e + g.ki_xy * self.integral + g.kd_xy * de
        v_down = -g.kp_z * (phi[2] - self.task.spread_target)
        vel = np.array([
            float(np.clip(-down, -u.v_xy_mps, u.v_xy_mps)),
            float(np.clip(right, -u.v_xy_mps, u.v_xy_mps)),
            float(np.clip(v_down, -u.v_up_mps, u.v_down_mps)),
        ])  # fmt: skip
        return Proposal(Setpoint(vel_ned=vel, yaw=self.yaw))


@dataclass
class WaypointPilot:
    """Flies a list of NED waypoints [m] in order: proposes each as a position target until the
    vehicle has stayed within `accept_m` of it for `settle_s`, then the next; `done` after the
    last. `reached` holds the time each waypoint was left [s]."""

    waypoints: list[np.ndarray]
    accept_m: float = 1.0
    settle_s: float = 1.0
    name: str = "square"
    index: int = 0
    since: float | None = None
    reached: list[float] = field(default_factory=list)

    @property
    def done(self) -> bool:
        return self.index >= len(self.waypoints)

    def propose(self, o: Observation) -> Proposal:
        if not self.done:
            inside = np.linalg.norm(o.state.pos_ned - self.waypoints[self.index]) < self.accept_m
            self.since = (self.since if self.since is not None else o.t) if inside else None
            if self.since is not None and o.t - self.since >= self.settle_s - 1e-9:
                self.index, self.since = self.index + 1, None
                self.reached.append(o.t)
        target = self.waypoints[min(self.index, len(self.waypoints) - 1)]
        return Proposal(Setpoint(pos_ned=np.array(target, dtype=float), yaw=0.0))


DESCENT_PILOT = "descend"
"""The pilot name of the descent behind the net (mission.flight): its decisions are the
landing's, not the mission pilot's, and the mission's metrics leave them out."""


@dataclass
class DescentPilot:
    """The landing's descent behind the net: back over the point where the mission ended, down
    to `goal_down_m` (NED about home), as velocity commands the envelope accepts as they are —
    a P law (0.5 /s) limited to 90 % of the envelope's speed rows and, around the present
    velocity, to 80 % of what its acceleration and tilt rows allow in one velocity-loop time
    constant (a position setpoint 12 m below would imply a step the rows refuse)."""

    north_m: float
    east_m: float
    goal_down_m: float
    limits: object  # safety.envelope.Limits of the flight's envelope
    tau_s: float  # the envelope's velocity-loop time constant [s]
    name: str = DESCENT_PILOT

    def propose(self, o: Observation) -> Proposal:
        from skyherd.flight.geo import GRAVITY
        from skyherd.safety.drills import slew

        lim, p, v = self.limits, o.state.pos_ned, o.state.vel_ned
        u = 0.5 * (np.array([self.north_m, self.east_m, self.goal_down_m]) - p)
        h = float(np.hypot(u[0], u[1]))
        if h > 0.9 * lim.speed_h_mps:
            u[:2] *= 0.9 * lim.speed_h_mps / h
        u[2] = float(np.clip(u[2], -0.9 * lim.climb_mps, 0.9 * lim.descent_mps))
        a_h = min(lim.accel_h_mps2, GRAVITY * np.tan(lim.tilt_cmd_rad))
        u = slew(u, v, 0.8 * a_h * self.tau_s, 0.8 * lim.accel_v_mps2 * self.tau_s)
        return Proposal(Setpoint(vel_ned=u, yaw=0.0))


@dataclass
class DrillPilot:
    """A drill's adversarial AI (safety.drills.Script) as a mission pilot: the same mission
    code, MAVLink path and SafetyNet as `skyherd fly`, with the drill's scripted attack in place
    of the policy (a drill = a mission with an adversarial pilot).

    It first flies to the script's start point (the drills' behave law), then runs the script on
    its own clock from there: `attack` in [t_on, t_off), `behave` otherwise, for the script's
    duration; `done` after it. A stall proposes no action (the net sees the deadline pass).
    `air_start`: the vehicle was started at the script's start point (a moving fixed-wing
    never stops there): the script's clock starts at the first decision.

    A drill judged on its recovery (`recovery_s` > 0: the airframe's recovery allowance,
    safety.drills.recovery_allowance_s) runs at least its attack + the allowance, and each time
    the net (`net_mode()`) leaves the AI it runs one allowance more, up to RECOVERY_ROUNDS
    allowances past that: the rule of the in-process drills (safety.drills.run_drill)."""

    script: object  # safety.drills.Script
    params: object  # safety.drills.DrillParams
    duration_s: float = 35.0
    name: str = "drill"
    t0: float | None = None  # the script's clock starts at the start point [s]
    t: float = 0.0
    air_start: bool = False
    recovery_s: float = 0.0  # 0: not judged on its recovery (the script's duration only)
    net_mode: Callable[[], object] | None = None  # the net's mode now (safety.supervisor.Mode)
    _ai: bool = True

    def __post_init__(self) -> None:
        from skyherd.safety.drills import RECOVERY_ROUNDS

        if self.recovery_s > 0:
            self.duration_s = max(self.duration_s, self.script.t_off + self.recovery_s)
        self.last_call_s = self.duration_s + RECOVERY_ROUNDS * self.recovery_s

    @property
    def done(self) -> bool:
        return self.t0 is not None and self.t - self.t0 >= self.duration_s - 1e-9

    def propose(self, o: Observation) -> Proposal:
        from skyherd.safety.drills import toward

        s, self.t = self.script, o.t
        if self.t0 is None and self.air_start:
            self.t0 = o.t
        if self.t0 is None:
            there = np.linalg.norm(o.state.pos_ned - s.start_ned) < 1.0
            if not (there and np.linalg.norm(o.state.vel_ned) < 0.5):
                return Proposal(toward(s.start_ned, 3.0, 1.0, self.params)(0.0, o.state))
            self.t0 = o.t
        tr = o.t - self.t0
        if self.recovery_s > 0 and self.net_mode is not None:
            ai = getattr(self.net_mode(), "value", None) == "ai"
            if self._ai and not ai:  # the net left the AI: time to recover
                self.duration_s = min(self.last_call_s, max(self.duration_s, tr + self.recovery_s))
            self._ai = ai
        return Proposal(s.act(tr, o.state, self.params))
