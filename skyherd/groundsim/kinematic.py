"""A numpy unicycle world for N UGVs: fast, exact, for training and long runs.

Per step of dt [s] with command (v_c, ω) from the behaviour:
  v ← v + clip(v_c − v, −a_max·dt, a_max·dt)           (speed slews at a_max)
  ψ(t) = ψ0 + ω·t, and the position follows the exact arc for constant (v, ω):
  n ← n + v/ω · (sin(ψ0 + ω dt) − sin ψ0),  e ← e + v/ω · (cos ψ0 − cos(ψ0 + ω dt))
  (the straight line v·dt·(cos ψ0, sin ψ0) when |ω| is tiny).
"""

from __future__ import annotations

import numpy as np

from skyherd.groundsim.behaviours import Behaviour, DriveParams, UGVCommand, wrap_pi
from skyherd.groundsim.ugv import UGVStates


def unicycle_step(states: UGVStates, cmd: UGVCommand, dt: float, p: DriveParams) -> UGVStates:
    """One exact unicycle step for all UGVs (pure function)."""
    dv = np.clip(cmd.v - states.speed, -p.accel_max * dt, p.accel_max * dt)
    v = np.clip(states.speed + dv, 0.0, p.v_max)
    w = np.clip(cmd.omega, -p.omega_max, p.omega_max)
    psi0 = states.heading
    psi1 = psi0 + w * dt
    small = np.abs(w) < 1e-9
    ws = np.where(small, 1.0, w)
    dn = np.where(small, v * dt * np.cos(psi0), v / ws * (np.sin(psi1) - np.sin(psi0)))
    de = np.where(small, v * dt * np.sin(psi0), v / ws * (np.cos(psi0) - np.cos(psi1)))
    pos = states.pos_ne + np.stack([dn, de], axis=-1)
    return UGVStates(pos, wrap_pi(psi1), v, np.asarray(cmd.camouflaged, dtype=bool))


class KinematicWorld:
    """N UGVs driven by a behaviour, integrated with `unicycle_step`.

    `step(t, dt)`: t is the shared simulation clock's time [s] at the start of the step
    (flight.clock.SimClock.t), dt the step [s]. Returns the new states.
    """

    def __init__(self, states: UGVStates, behaviour: Behaviour, params: DriveParams):
        self.states = states
        self.behaviour = behaviour
        self.p = params

    def step(self, t: float, dt: float) -> UGVStates:
        if not dt > 0:
            raise ValueError(f"dt must be > 0, got {dt}")
        cmd = self.behaviour.command(t, self.states)
        self.states = unicycle_step(self.states, cmd, dt, self.p)
        return self.states
