"""skyherd's vehicle models behind an autopilot's outputs: the bodies the bridges step.

`QuadBody` is the numba quadrotor of `flight/quadrotor.py` stepped directly on its flat
arrays (no per-step allocation): motor commands in [0, 1] in quad-X order
  1 front right CCW, 2 rear left CCW, 3 front left CW, 4 rear right CW
which is at once PX4's order for `none_iris` (CA_ROTOR0..3 with KM +,+,−,−) and
ArduCopter's X-frame order; the airframe file uses the same order, and `QuadBody`
refuses an airframe that does not.

`PlaneBody` is the JSBSim fixed-wing of `flight/fixedwing/jsbsim_model.py`; JSBSim keeps
its own fixed step, and an autopilot frame of another length is covered by as many whole
JSBSim steps as fit into the frames so far (the state is held in between).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from skyherd.flight.fixedwing.jsbsim_model import JSBSimPlane, ModelParams, Surfaces
from skyherd.flight.geo import Home
from skyherd.flight.quadrotor import (
    A_ON_GROUND,
    A_SPECIFIC,
    X_MOTOR,
    Quadrotor,
    QuadrotorParams,
)
from skyherd.flight.quadrotor_kernels import physics_steps
from skyherd.flight.state import VehicleState

# out vector of `quad_step_pwm` / `QuadBody.out`: what both bridges report each frame
O_GYRO, O_ACCEL, O_POS, O_QUAT, O_VEL = 0, 3, 6, 9, 13
N_OUT = 16
QUAD_X_SPIN = (1.0, 1.0, -1.0, -1.0)  # +1 CCW seen from above, motors 1..4


@njit(cache=True)
def _gather(x, aux, out):
    for k in range(3):
        out[O_GYRO + k] = x[10 + k]
        out[O_ACCEL + k] = aux[A_SPECIFIC + k]
        out[O_POS + k] = x[k]
        out[O_VEL + k] = x[3 + k]
    for k in range(4):
        out[O_QUAT + k] = x[6 + k]


@njit(cache=True)
def quad_step(x, aux, p, u, dt, max_h, out):
    """Step the quadrotor by dt [s] (substeps <= max_h) under u (4,), then fill out (16,)."""
    n = max(1, math.ceil(dt / max_h - 1e-9))
    physics_steps(x, aux, p, u, dt / n, n)
    _gather(x, aux, out)


@njit(cache=True)
def quad_step_pwm(rx, pwm_min, pwm_max, x, aux, p, u, dt, max_h, out):
    """Decode motors 1..4 from an ArduPilot servo packet in rx (uint8) and step (see above).

    PWM [µs] → command (pwm − pwm_min)/(pwm_max − pwm_min), clipped to [0, 1] by the model.
    """
    span = pwm_max - pwm_min
    for i in range(4):
        pwm = rx[8 + 2 * i] | (rx[9 + 2 * i] << 8)
        u[i] = (pwm - pwm_min) / span
    quad_step(x, aux, p, u, dt, max_h, out)


class QuadBody:
    """The numba quadrotor at rest at home; `step` advances it, `out` holds the result."""

    def __init__(self, params: QuadrotorParams | None = None):
        params = params if params is not None else QuadrotorParams()
        if tuple(params.spin) != QUAD_X_SPIN:
            raise ValueError(
                f"airframe {params.name!r}: spin {params.spin} is not quad-X order "
                f"(1 FR CCW, 2 RL CCW, 3 FL CW, 4 RR CW)"
            )
        self.params = params
        self.model = Quadrotor(params)  # owns x, aux, p
        self.u = np.zeros(4)
        self.out = np.zeros(N_OUT)
        self.t = 0.0  # simulation time [s]
        self.reset()

    def reset(self) -> None:
        """Back on the ground at home, motors stopped, time 0."""
        self.model.reset()
        self.u[:] = 0.0
        self.t = 0.0
        _gather(self.model.x, self.model.aux, self.out)

    def step(self, dt: float, u) -> None:
        """Advance by dt [s] holding motor commands u (4,) in [0, 1] (NaN counts as 0)."""
        self.u[:] = u
        quad_step(
            self.model.x, self.model.aux, self.model.p, self.u, dt, self.params.physics_dt, self.out
        )
        self.t += dt

    @property
    def motor_speed(self) -> np.ndarray:
        return self.model.x[X_MOTOR:].copy()

    def state(self) -> VehicleState:
        o = self.out
        return VehicleState(
            t=self.t,
            pos_ned=o[O_POS : O_POS + 3].copy(),
            vel_ned=o[O_VEL : O_VEL + 3].copy(),
            quat=o[O_QUAT : O_QUAT + 4].copy(),
            omega_frd=o[O_GYRO : O_GYRO + 3].copy(),
            accel_frd=o[O_ACCEL : O_ACCEL + 3].copy(),
            on_ground=bool(self.model.aux[A_ON_GROUND] > 0.5),
        )


class PlaneBody:
    """The JSBSim fixed-wing on its wheels at home, engine running (throttle decides)."""

    def __init__(self, home: Home, params: ModelParams | None = None):
        self.plane = JSBSimPlane(home=home, params=params if params is not None else ModelParams())
        self.h = self.plane.params.physics_dt
        self.out = np.zeros(N_OUT)
        self.reset()

    def reset(self) -> None:
        self.plane.reset_on_ground()
        self.plane.set_engine(True)
        self.t = 0.0  # frame time [s]
        self._n_jsb = 0  # whole JSBSim steps taken
        self._state = self.plane.state()
        self._fill()

    def _fill(self) -> None:
        s, o = self._state, self.out
        o[O_GYRO : O_GYRO + 3] = s.omega_frd
        o[O_ACCEL : O_ACCEL + 3] = s.accel_frd
        o[O_POS : O_POS + 3] = s.pos_ned
        o[O_QUAT : O_QUAT + 4] = s.quat
        o[O_VEL : O_VEL + 3] = s.vel_ned

    def step(self, dt: float, surfaces: Surfaces) -> None:
        """Advance frame time by dt [s]; JSBSim runs the whole steps that now fit."""
        self.t += dt
        n = int(self.t / self.h + 1e-9) - self._n_jsb
        if n > 0:
            self._state = self.plane.step(n * self.h, surfaces)
            self._n_jsb += n
            self._fill()

    @property
    def airspeed(self) -> float:
        return self.plane.airspeed

    def state(self) -> VehicleState:
        s = self._state
        return VehicleState(
            self.t, s.pos_ned, s.vel_ned, s.quat, s.omega_frd, s.accel_frd, s.on_ground
        )
