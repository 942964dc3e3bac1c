"""Quad-X mixer: collective thrust and body torques → four motor commands, with saturation.

Allocation (rotor i at (x_i, y_i) FRD, spin s_i = +1 CCW from above, c = k_torque/k_thrust):
    [T, τx, τy, τz]ᵀ = A t,   A = [[1 1 1 1], [−y_i], [x_i], [c·s_i]],   t_i rotor thrusts [N]
The mixer uses B = A⁻¹. Saturation priority (PX4 style, airmode off): roll/pitch are scaled
down when their spread alone exceeds the motor range; then the collective is shifted to fit;
yaw gets what headroom is left. Motor command u_i = sqrt(t_i / t_max) since t = k_f (u ω_max)².
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

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


@njit(cache=True, fastmath=False)
def mix(b, t_lo, t_hi, thrust, tx, ty, tz, u, work):
    """Write motor commands u (4,) in [0, 1]; return saturation flags (sum of SAT_*).

    b (16,) row-major allocation inverse; t_lo, t_hi per-rotor thrust bounds [N];
    work (12,) scratch space (no allocation on the hot path).
    """
    rp = work[0:4]
    yw = work[4:8]
    s = work[8:12]
    flags = 0.0
    rmax = -1e30
    rmin = 1e30
    for i in range(4):
        rp[i] = b[4 * i + 1] * tx + b[4 * i + 2] * ty
        yw[i] = b[4 * i + 3] * tz
        rmax = max(rmax, rp[i])
        rmin = min(rmin, rp[i])
    avail = t_hi - t_lo
    k = 1.0
    if rmax - rmin > avail:
        k = avail / (rmax - rmin)
        flags += SAT_RP
    hi = -1e30
    lo = 1e30
    for i in range(4):
        s[i] = b[4 * i] * thrust + k * rp[i]
        hi = max(hi, s[i])
        lo = min(lo, s[i])
    shift = 0.0
    if hi > t_hi:
        shift = t_hi - hi
        flags += SAT_THRUST_UP
    elif lo < t_lo:
        shift = t_lo - lo
        flags += SAT_THRUST_DN
    ky = 1.0
    for i in range(4):
        s[i] += shift
        if yw[i] > 1e-12:
            ky = min(ky, (t_hi - s[i]) / yw[i])
        elif yw[i] < -1e-12:
            ky = min(ky, (t_lo - s[i]) / yw[i])
    if ky < 1.0:
        ky = max(ky, 0.0)
        flags += SAT_YAW
    for i in range(4):
        ti = s[i] + ky * yw[i]
        ti = min(max(ti, t_lo), t_hi)
        u[i] = math.sqrt(ti / t_hi) if t_hi > 0.0 else 0.0
    return flags
