"""Quad-X mixer: collective thrust and body torques → four motor commands, with saturation.

Allocation (rotor i at (x_i, y_i) FRD, spin s_i = +1 CCW from above, c = k_torque/k_thrust):
    [T, τx, τy, τz]ᵀ = A t,   A = [[1 1 1 1], [−y_i], [x_i], [c·s_i]],   t_i rotor thrusts [N]
The mixer uses B = A⁻¹. Saturation priority (PX4 style, airmode off): roll/pitch are scaled
down when their spread alone exceeds the motor range; then the collective is shifted to fit;
yaw gets what headroom is left. Motor command u_i = sqrt(t_i / t_max) since t = k_f (u ω_max)².
The kernel, `mix`, is compiled with the loops that call it (control.py); this module is plain
numpy (the autopilot builds B without importing numba).
"""

from __future__ import annotations

import numpy as np

SAT_RP = 1.0  # roll/pitch torque was reduced
SAT_YAW = 2.0  # yaw torque was reduced
SAT_THRUST_UP = 4.0  # collective lowered to make room
SAT_THRUST_DN = 8.0  # collective raised to keep motors above idle


def allocation_inverse(rotor_xy: np.ndarray, spin: np.ndarray, k_thrust: float, k_torque: float):
    """B (4, 4): rotor thrusts [N] = B @ (T [N], τx, τy, τz [N m])."""
    a = np.vstack(
        [np.ones(4), -rotor_xy[:, 1], rotor_xy[:, 0], (k_torque / k_thrust) * np.asarray(spin)]
    )
    return np.linalg.inv(a)
