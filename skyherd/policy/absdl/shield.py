"""Shielded training: the SafetyNet `skyherd fly` flies certifies every training action.

One `safety.net.SafetyNet` per episode, loaded from the same constraint set as the flown
ground-air mission (safety/envelopes/quadrotor_groundair.toml) and handed over at t = 0 as the
companion does. Each decision it is fed the link and camera as fresh (the training simulator
has both every step) and the UAV's state, and `certify` returns the command it would fly:
the proposal as it is (accepted), projected onto the envelope, or the fallback's hold (zero
velocity; a position hold has none). `changed` counts the decisions whose certified command
differs from the proposal, as decisions.jsonl's verdict does in flight.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.policy.absdl.env import ENVELOPE_FILE

LEVEL = np.array([1.0, 0.0, 0.0, 0.0])


@dataclass
class ShieldStats:
    decisions: int = 0
    changed: int = 0  # verdict other than accepted
    verdicts: dict[str, int] = field(default_factory=dict)

    @property
    def fraction(self) -> float:
        return self.changed / self.decisions if self.decisions else 0.0

    def add(self, other: ShieldStats) -> None:
        self.decisions += other.decisions
        self.changed += other.changed
        for k, n in other.verdicts.items():
            self.verdicts[k] = self.verdicts.get(k, 0) + n


class Shield:
    """certify(t, uav_state, v_proposed) → (v_certified (3,), verdict); `reset()` per episode."""

    def __init__(self):
        from skyherd.safety.config import ENVELOPE_DIR

        self.path = ENVELOPE_DIR / ENVELOPE_FILE
        self.stats = ShieldStats()
        self.net = None

    def reset(self) -> None:
        from skyherd.safety.net import SafetyNet

        self.net = SafetyNet.load("quadrotor", self.path, camera=True)
        self.net.handover(0.0, FlightMode.OFFBOARD)

    def certify(self, t: float, uav: dict[str, float], v) -> tuple[np.ndarray, str]:
        if self.net is None:
            self.reset()
        net = self.net
        net.link(t, t)
        net.frame(t, t)
        state = VehicleState(
            t=t,
            pos_ned=np.array([uav["n"], uav["e"], uav["d"]]),
            vel_ned=np.array([uav["vn"], uav["ve"], uav["vd"]]),
            quat=LEVEL,
            omega_frd=np.zeros(3),
            accel_frd=np.array([0.0, 0.0, -GRAVITY]),
            on_ground=False,
        )
        v = np.asarray(v, float)
        d = net.step(t, state, Setpoint(vel_ned=v.copy(), yaw=0.0))
        cmd = d.command.vel_ned if d.command is not None else None
        out = np.zeros(3) if cmd is None else np.asarray(cmd, float).copy()
        if not np.all(np.isfinite(out)):
            out = np.zeros(3)
        verdict = d.verdict
        s = self.stats
        s.decisions += 1
        s.verdicts[verdict] = s.verdicts.get(verdict, 0) + 1
        if verdict != "accepted":
            s.changed += 1
        return out, verdict
