"""Monitor: is a proposed command inside the envelope, which rows bind, how close it comes.

The fast path is `worst(z)` (compiled, ~1 µs); the explanation (`check`) is built only when
someone reads it. z is assembled from a VehicleState and a velocity command (NED, m/s).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.flight.state import VehicleState
from skyherd.safety.envelope import NZ, Envelope, P, U, V


def make_z(
    state: VehicleState, u_ned: np.ndarray | None, out: np.ndarray | None = None
) -> np.ndarray:
    """z (NZ,) from a state and a velocity command (3,) [m/s NED]; u None → hold (u = 0)."""
    z = np.empty(NZ) if out is None else out
    z[P] = state.pos_ned
    z[V] = state.vel_ned
    w, x, y, q3 = state.quat.tolist()  # roll, pitch as flight.frames.quat_to_euler (ZYX)
    z[6] = math.atan2(2 * (w * x + y * q3), 1 - 2 * (x * x + y * y))
    sp = 2 * (w * y - q3 * x)
    z[7] = math.asin(1.0 if sp > 1.0 else (-1.0 if sp < -1.0 else sp)) if sp == sp else math.nan
    if u_ned is None:
        z[U] = 0.0
    else:
        z[U] = u_ned
    return z


@dataclass(frozen=True)
class Check:
    """A monitor verdict. worst: largest residual (<= 0 inside; NaN for non-finite input);
    violated / near: [(row name, residual)] of the polyhedron it was judged against."""

    ok: bool
    worst: float
    violated: tuple[tuple[str, float], ...]
    near: tuple[tuple[str, float], ...]

    @property
    def reason(self) -> str:
        if self.ok:
            return ""
        if not self.violated:
            return "non-finite state or action"
        name, res = self.violated[0]
        return name if not math.isfinite(res) else f"{name} (by {res:.2f})"


class Monitor:
    """Checks z = (state, command) against one envelope (predictive) and reports margins."""

    def __init__(self, envelope: Envelope):
        self.envelope = envelope
        spec = envelope.spec
        self.alpha = min(spec.dynamics.dt_s / spec.dynamics.tau_s, 1.0)
        self.dt = spec.dynamics.dt_s

    def worst(self, z: np.ndarray) -> float:
        """Fast path: largest residual (<= 0 inside, NaN for non-finite z)."""
        return self.envelope.worst(z)

    def check(self, z: np.ndarray) -> Check:
        w = self.envelope.worst(z)
        ok = w <= 0.0  # False for NaN
        return Check(
            ok=bool(ok),
            worst=float(w),
            violated=tuple(self.envelope.violated(z)) if not ok else (),
            near=tuple(self.envelope.nearly_active(z)),
        )

    def predict(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One step of the envelope's model (module eq. 1-2 of safety.envelope): (p', v')."""
        v1 = (1 - self.alpha) * z[V] + self.alpha * z[U]
        return z[P] + self.dt * v1, v1

    def stopping_distance(self, v_ned: np.ndarray) -> tuple[float, float]:
        """Exact braking distance [m] horizontally and vertically from velocity v (3,) at the
        envelope's deceleration: s^2 / (2 a) + s t_react (inf horizontally if it cannot stop)."""
        d = self.envelope.spec.dynamics
        sh = float(np.hypot(v_ned[0], v_ned[1]))
        sv = abs(float(v_ned[2]))
        h = sh * sh / (2 * d.decel_h_mps2) + sh * d.react_s if d.decel_h_mps2 > 0 else math.inf
        return h, sv * sv / (2 * d.decel_v_mps2) + sv * d.react_s
