"""Inner loops of the fixed-wing: bank and pitch angle hold, turn coordination.

PID on the attitude errors with rate damping; the coordinated-turn rates
q = (g/V) tan φ sin φ and r = (g/V) sin φ cos θ are fed forward, and so is the extra
incidence a turn needs, α_1g·(1/cos φ − 1) (α_1g ≈ CL/CL_α ≈ 0.2 rad for the J3Cub at 24 m/s). Surface effectiveness grows
with dynamic pressure, so the gains are scaled by (V_trim / V)^2 (clipped to [0.5, 2]).
Surfaces are in the `jsbsim_model.Surfaces` convention (+ rolls right, + noses up, + yaws right).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from skyherd.flight.frames import wrap_pi
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState


@dataclass(frozen=True)
class InnerGains:
    """Attitude and ground-steering gains, at the trim airspeed (scaled by (V_trim/V)^2)."""

    roll_p: float = 4.0  # aileron per rad of bank error
    roll_d: float = 0.8  # aileron per rad/s of roll rate
    roll_i: float = 2.0  # aileron per rad·s
    pitch_p: float = 2.0  # elevator per rad of pitch error
    pitch_d: float = 0.6  # elevator per rad/s of pitch rate error
    pitch_i: float = 1.0  # elevator per rad·s
    yaw_p: float = 1.5  # rudder per rad/s of yaw-rate error (turn coordination, yaw damper)
    steer_p: float = 2.5  # rudder per rad of heading error on the ground
    steer_d: float = 1.2  # rudder per rad/s of yaw rate on the ground
    course_k: float = 0.6  # [1/s] course error → turn rate (offboard velocity, manual modes)
    turn_pitch: float = 0.25  # [rad] α_1g: pitch added in a turn, α_1g·(1/cos φ − 1)


class AttitudeController:
    """Roll, pitch and yaw-rate loops → (aileron, elevator, rudder). State: two integrators."""

    def __init__(self, gains: InnerGains | None = None):
        self.g = gains or InnerGains()
        self.reset()

    def reset(self, elevator_trim: float = 0.0) -> None:
        self.roll_i = 0.0
        self.pitch_i = elevator_trim

    def update(
        self, st: VehicleState, bank: float, pitch_dem: float, v: float, v_trim: float, dt: float
    ) -> tuple[float, float, float]:
        """bank, pitch_dem [rad]; v, v_trim airspeeds [m/s]; dt [s]."""
        g = self.g
        roll, pitch, _ = st.euler
        p, q, r = st.omega_frd
        v = max(v, 5.0)
        scale = min(2.0, max(0.5, (v_trim / v) ** 2))
        e_roll = wrap_pi(bank - roll)
        self.roll_i = min(0.2, max(-0.2, self.roll_i + g.roll_i * e_roll * dt))
        ail = scale * (g.roll_p * e_roll - g.roll_d * p) + self.roll_i
        q_ff = GRAVITY / v * math.tan(roll) * math.sin(roll)
        r_ff = GRAVITY / v * math.sin(roll) * math.cos(pitch)
        # A banked wing needs n = 1/cos φ times the lift: about α_1g·(n − 1) more incidence.
        pitch_dem += g.turn_pitch * (1.0 / max(0.5, math.cos(roll)) - 1.0)
        e_pitch = pitch_dem - pitch
        el = scale * (g.pitch_p * e_pitch + g.pitch_d * (q_ff - q)) + self.pitch_i
        if abs(el) < 1.0 or el * e_pitch < 0:  # anti-windup: integrate only off the stop
            self.pitch_i = min(1.0, max(-1.0, self.pitch_i + g.pitch_i * e_pitch * dt))
        rud = scale * g.yaw_p * (r_ff - r)
        return ail, el, rud

    def wings_level_aileron(self, st: VehicleState) -> float:
        """Aileron holding the wings level on the ground (no integrator)."""
        return self.g.roll_p * (0.0 - st.euler[0]) - self.g.roll_d * st.omega_frd[0]
