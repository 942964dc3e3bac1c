"""L1 lateral guidance for straight tracks and loiter circles.

After Park, Deyst & How, "A New Nonlinear Guidance Logic for Trajectory Tracking" (AIAA GNC
2004), in the form ArduPilot's AP_L1_Control uses (L1 distance from a period and damping,
and a PD + centripetal law on the circle). All vectors are horizontal (north, east) [m] or
[m/s], given as (2,) arrays; a positive lateral acceleration [m/s^2] turns right (clockwise
seen from above). Scalar math inside: these run at the control rate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def cross2(a, b) -> float:
    """z of a × b in (north, east): > 0 when b points to the right of a."""
    return float(a[0] * b[1] - a[1] * b[0])


@dataclass(frozen=True)
class L1Params:
    """period [s] and damping [-] of the L1 loop (ArduPilot NAVL1_PERIOD / NAVL1_DAMPING)."""

    period: float = 17.0
    damping: float = 0.75


@dataclass(frozen=True)
class LateralDemand:
    """lat_acc [m/s^2] (+ right), cross-track error [m] (+ right of the path, or outside
    the circle), and `nu` [rad], the angle from the ground velocity to the L1 line of sight."""

    lat_acc: float
    xtrack: float
    nu: float


def l1_distance(p: L1Params, ground_speed: float) -> float:
    """L1 = damping · period · V / pi [m] (AP_L1_Control)."""
    return p.damping * p.period * max(ground_speed, 1.0) / math.pi


def _clip_half_pi(x: float) -> float:
    return max(-math.pi / 2, min(math.pi / 2, x))


def track(
    p: L1Params, pos: np.ndarray, vel: np.ndarray, a: np.ndarray, b: np.ndarray
) -> LateralDemand:
    """Follow the line from `a` to `b` (both (2,) [m]); pos, vel (2,) about the same origin.

    Nu1 = angle of the ground velocity to the track, Nu2 = asin(xtrack / L1);
    a_lat = K_L1 · V^2 / L1 · sin(Nu1 + Nu2), K_L1 = 4 ζ^2 (Park et al. eq. 1).
    """
    vn, ve = float(vel[0]), float(vel[1])
    v = max(math.hypot(vn, ve), 1.0)
    l1 = l1_distance(p, v)
    k_l1 = 4.0 * p.damping**2
    abn, abe = float(b[0] - a[0]), float(b[1] - a[1])
    n = math.hypot(abn, abe)
    if n < 1e-3:
        return circle_capture(p, pos, vel, b)
    abn, abe = abn / n, abe / n
    rn, re = float(pos[0] - a[0]), float(pos[1] - a[1])
    xtrack = rn * abe - re * abn  # > 0: vehicle left of the track, must turn right
    along = rn * abn + re * abe
    # Behind `a` and farther than L1 from it: fly straight at `a` first.
    if along < 0.0 and math.hypot(rn, re) > l1:
        return circle_capture(p, pos, vel, a)
    nu1 = math.atan2(vn * abe - ve * abn, vn * abn + ve * abe)
    nu2 = math.asin(max(-1.0, min(1.0, xtrack / l1)))
    nu = _clip_half_pi(nu1 + nu2)
    return LateralDemand(k_l1 * v * v / l1 * math.sin(nu), -xtrack, nu)


def circle_capture(
    p: L1Params, pos: np.ndarray, vel: np.ndarray, target: np.ndarray
) -> LateralDemand:
    """Head straight for `target` (2,) [m]: the L1 line of sight is the target itself."""
    vn, ve = float(vel[0]), float(vel[1])
    v = max(math.hypot(vn, ve), 1.0)
    ln, le = float(target[0] - pos[0]), float(target[1] - pos[1])
    if math.hypot(ln, le) < 1e-3:
        return LateralDemand(0.0, 0.0, 0.0)
    nu = _clip_half_pi(math.atan2(vn * le - ve * ln, vn * ln + ve * le))
    k_l1 = 4.0 * p.damping**2
    return LateralDemand(k_l1 * v * v / l1_distance(p, v) * math.sin(nu), 0.0, nu)


def loiter(
    p: L1Params, pos: np.ndarray, vel: np.ndarray, center: np.ndarray, radius: float, direction: int
) -> LateralDemand:
    """Circle `center` (2,) at `radius` [m]; direction +1 clockwise (right turns), -1 counter.

    On the circle: a = dir · (Kx·e_r + Kv·ė_r + V_t^2 / r) (PD on the radial error plus the
    centripetal term, Kx = ω^2, Kv = 2ζω, ω = 2π/period). Outside it, the capture law
    (straight for the centre) is flown until the two demands cross (AP_L1_Control).
    """
    omega = 2.0 * math.pi / p.period
    kx, kv = omega * omega, 2.0 * p.damping * omega
    rn, re = float(pos[0] - center[0]), float(pos[1] - center[1])
    d = math.hypot(rn, re)
    if d < 1e-3:
        rn, re, d = 1.0, 0.0, 1.0
    rn, re = rn / d, re / d
    vn, ve = float(vel[0]), float(vel[1])
    err = d - radius  # > 0 outside
    v_t = (rn * ve - re * vn) * direction  # > 0 when going round the right way
    circ_pd = kx * err + kv * (vn * rn + ve * re)  # toward the centre when > 0
    if v_t < 0.0:  # going the wrong way round: never let the PD turn us further out
        circ_pd = max(circ_pd, 0.0)
    centripetal = v_t * v_t / max(0.5 * radius, radius + err)
    a_circ = direction * (circ_pd + centripetal)
    if err > 0.0:
        cap = circle_capture(p, pos, vel, center)
        # Outside the circle, fly the capture law until the two demands cross (seamless).
        if direction * cap.lat_acc < direction * a_circ:
            return LateralDemand(cap.lat_acc, err, cap.nu)
    return LateralDemand(a_circ, err, 0.0)
