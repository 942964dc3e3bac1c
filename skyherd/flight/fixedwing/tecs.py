"""Total-energy control of altitude and airspeed (TECS).

After Lambregts, "Vertical Flight Path and Speed Control Autopilot Design Using Total Energy
Principles" (AIAA 83-2239). With flight-path angle γ = ḣ/V and the specific energy rate
normalised by V·g:

    total        Ė/(V g) = γ + V̇/g           → throttle (thrust changes total energy)   (1)
    distribution  Ḋ/(V g) = γ − V̇/g           → pitch (trades height for speed)          (2)

Height and speed errors become demanded rates through first-order loops (3), rate-limited
to the climb / sink and acceleration limits. A speed weight w ∈ [0, 2] scales the two
terms of (2): w = 1 normal, w = 2 pitch for speed only (take-off climb, stall protection),
w = 0 pitch for height only (flare). Throttle saturation is handled by freezing the
integrators that would push further into the limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from skyherd.flight.geo import GRAVITY


@dataclass(frozen=True)
class TecsGains:
    """Loop gains. Time constants [s]; throttle and pitch gains per unit of (1) / (2)."""

    height_tau: float = 4.0  # (3) ḣ_dem = (h_dem − h)/τ_h
    speed_tau: float = 2.5  # (3) V̇_dem = (V_dem − V)/τ_V
    accel_max: float = 1.5  # [m/s^2] |V̇_dem| limit
    thr_ff: float = 1.2  # throttle per unit of demanded (1)
    thr_p: float = 1.5
    thr_i: float = 0.4  # [1/s]
    pitch_ff: float = 1.0  # [rad] pitch per unit of demanded (2)
    pitch_p: float = 1.0
    pitch_i: float = 0.25  # [1/s]
    vdot_tau: float = 0.3  # [s] low-pass of the airspeed derivative


@dataclass(frozen=True)
class TecsOutput:
    throttle: float  # [0, 1]
    pitch: float  # [rad] demanded pitch angle
    hdot_dem: float  # [m/s]
    vdot_dem: float  # [m/s^2]


class Tecs:
    """State: two integrators and the filtered airspeed derivative. Time comes in as dt."""

    def __init__(self, gains: TecsGains | None = None):
        self.g = gains or TecsGains()
        self.reset()

    def reset(self, throttle_trim: float = 0.5, pitch_trim: float = 0.0) -> None:
        self._thr_int = throttle_trim
        self._pitch_int = pitch_trim
        self._v_prev: float | None = None
        self._vdot = 0.0

    def update(
        self,
        dt: float,
        h: float,
        hdot: float,
        v: float,
        h_dem: float,
        v_dem: float,
        *,
        climb_max: float,
        sink_max: float,
        thr_min: float,
        thr_max: float,
        pitch_min: float,
        pitch_max: float,
        speed_weight: float = 1.0,
        hdot_ff: float = 0.0,
    ) -> TecsOutput:
        """One step. h [m] up, hdot [m/s] up, v airspeed [m/s]; demands likewise."""
        g = self.g
        v = max(v, 3.0)
        if self._v_prev is None:
            self._v_prev = v
        raw = (v - self._v_prev) / dt
        self._v_prev = v
        a = dt / (g.vdot_tau + dt)
        self._vdot += a * (raw - self._vdot)

        # (3) demanded rates
        hdot_dem = (h_dem - h) / g.height_tau + hdot_ff
        hdot_dem = min(climb_max, max(-sink_max, hdot_dem))
        vdot_dem = min(g.accel_max, max(-g.accel_max, (v_dem - v) / g.speed_tau))

        gam, gam_dem = hdot / v, hdot_dem / v
        acc, acc_dem = self._vdot / GRAVITY, vdot_dem / GRAVITY

        # (1) total energy rate → throttle
        e_tot = (gam_dem - gam) + (acc_dem - acc)
        thr_unsat = g.thr_ff * (gam_dem + acc_dem) + g.thr_p * e_tot + self._thr_int
        if not ((thr_unsat >= thr_max and e_tot > 0) or (thr_unsat <= thr_min and e_tot < 0)):
            self._thr_int += g.thr_i * e_tot * dt
            self._thr_int = min(thr_max, max(thr_min - 0.5, self._thr_int))
        throttle = min(thr_max, max(thr_min, thr_unsat))

        # (2) energy distribution rate → pitch, weighted
        w = min(2.0, max(0.0, speed_weight))
        d_dem = (2.0 - w) * gam_dem - w * acc_dem
        d_err = (2.0 - w) * (gam_dem - gam) - w * (acc_dem - acc)
        pitch_unsat = g.pitch_ff * d_dem + g.pitch_p * d_err + self._pitch_int
        if not (
            (pitch_unsat >= pitch_max and d_err > 0) or (pitch_unsat <= pitch_min and d_err < 0)
        ):
            self._pitch_int += g.pitch_i * d_err * dt
            self._pitch_int = min(pitch_max, max(pitch_min, self._pitch_int))
        pitch = min(pitch_max, max(pitch_min, pitch_unsat))
        if not (math.isfinite(throttle) and math.isfinite(pitch)):  # never hand NaN onward
            self.reset()
            throttle, pitch = thr_min, 0.0
        return TecsOutput(throttle, pitch, hdot_dem, vdot_dem)
