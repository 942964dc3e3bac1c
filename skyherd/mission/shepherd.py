"""`--mission shepherd`: the UAV herds the UGV flock into the goal region (ref [16]).

A pilot (mission.pilots' interface) behind the same SafetyNet as the ground-air mission: at each
decision the selector (policy.shepherd.selector: Strömbom's rule or the learned one) picks the
sub-skill, collect or drive; the sub-skill's point (policy.shepherd.rules) becomes a horizontal
velocity toward it at the shepherd's speed (standing while a UGV is within 3 r_a), with a P law
holding the altitude; the command is limited to what the envelope's speed and acceleration rows
accept around the present velocity (as the landing's DescentPilot is), so the net certifies it
as it is. The flock's positions are the UGVs' own reports (`skyherd/ugv/<id>/state` on Zenoh,
what a real team would send by radio); the pilot is `done` once the flock's centre is in the
goal region, and the mission lands.

Each decision's explanation names the sub-skill, the selector's P(drive) and the features.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.groundsim.flock import FlockParams
from skyherd.mission.pilots import Observation, Proposal
from skyherd.policy.shepherd.episode import in_goal
from skyherd.policy.shepherd.rules import ShepherdParams, shepherd_velocity, skill_point
from skyherd.policy.shepherd.selector import features


@dataclass
class ShepherdPilot:
    """Selector → sub-skill → point → velocity. `flock(t)` returns the UGVs' positions (N, 2)
    [m] at tick time t, or None until every UGV has reported."""

    selector: object  # policy.shepherd.selector: .choose(pos, goal, flock) -> (skill, p_drive)
    flock: Callable[[float], np.ndarray | None]
    altitude_m: float
    limits: object  # safety.envelope.Limits of the flight's envelope
    tau_s: float  # the envelope's velocity-loop time constant [s]
    task: ShepherdParams = field(default_factory=ShepherdParams)
    flock_p: FlockParams = field(default_factory=FlockParams)
    k_alt: float = 0.5  # altitude P gain [1/s]
    name: str = "shepherd"
    t_goal: float | None = None  # when the flock's centre entered the goal region [s]
    skills: list = field(default_factory=list)  # (t, skill) per decision

    @property
    def done(self) -> bool:
        return self.t_goal is not None

    def propose(self, o: Observation) -> Proposal:
        from skyherd.flight.geo import GRAVITY
        from skyherd.safety.drills import slew

        lim, p, v = self.limits, o.state.pos_ned, o.state.vel_ned
        up = float(np.clip(self.k_alt * (-self.altitude_m - p[2]), -0.9 * lim.climb_mps,
                           0.9 * lim.descent_mps))  # fmt: skip
        pos = self.flock(o.t)
        if pos is None:  # no reports yet: hold here
            u = np.array([0.0, 0.0, up])
            return Proposal(
                Setpoint(vel_ned=u, yaw=0.0),
                -1,
                {"module": "wait", "reason": "no flock reports yet"},
            )
        if in_goal(pos, self.task) and self.t_goal is None:
            self.t_goal = o.t
        skill, p_drive = self.selector.choose(pos, self.task.goal_ne, self.flock_p)
        target = skill_point(skill, pos, self.task.goal_ne, self.flock_p)
        vh = shepherd_velocity(p[:2], target, pos, self.flock_p, self.task)
        u = np.array([vh[0], vh[1], up])
        a_h = min(lim.accel_h_mps2, GRAVITY * np.tan(lim.tilt_cmd_rad))
        u = slew(u, v, 0.8 * a_h * self.tau_s, 0.8 * lim.accel_v_mps2 * self.tau_s)
        self.skills.append((o.t, skill))
        x = features(pos, self.task.goal_ne, self.flock_p)
        why = {"module": skill, "reason": f"{self.selector.name} selector, P(drive) = {p_drive:.2f}",
               "concepts": {"p_drive": round(p_drive, 4), "furthest_over_f": round(float(x[0]), 4),
                            "spread_over_f": round(float(x[1]), 4),
                            "goal_distance_over_f": round(float(x[2]), 4),
                            "target_n": round(float(target[0]), 2), "target_e": round(float(target[1]), 2)}}  # fmt: skip
        return Proposal(Setpoint(vel_ned=u, yaw=0.0), -1, why)


def flock_reader(
    subscriber, n: int, patience_s: float = 5.0
) -> Callable[[float], np.ndarray | None]:
    """The flock's reported positions (N, 2) at tick time t, from a
    groundsim.transport.UGVStateSubscriber: the simulator publishes them at each camera instant
    before it marks the tick, so the reader waits (at most `patience_s` of wall time) until
    every UGV's report of instant t is in; in lockstep nothing newer can come before the tick
    closes, so the flight does not depend on Zenoh's delivery time. Free-running, or when
    reports stop, the newest ones (None before every UGV reported once)."""

    def read(t: float):
        deadline = time.monotonic() + patience_s
        while True:
            if subscriber.oldest_stamp(n) >= t - 1e-6 or time.monotonic() > deadline:
                break
            time.sleep(0.001)
        s = subscriber.states(n)
        return None if s is None else s.pos_ne

    return read
