"""Separation from other vehicles as constraint rows of the supervisor (one half-plane each).

For vehicle k and another vehicle j (positions p, velocities v, NED [m, m/s], one frame),
with n the unit vector from j to k, the relative stopping point must keep `radius_m`:

    n·(p_k' − p_j) + T n·(v_k' − v_j) >= radius_m                                   (S1)

p_k', v_k' the envelope's one-step prediction (safety.envelope eq. 1-2) and T its horizontal
stopping time (eq. 3): both vehicles brake alike when their nets fall back, so the relative
motion decides. (S1) is linear in z = (p, v, attitude, u) of vehicle k, the half-plane
tangent to the ball of radius `radius_m` about j seen from k: conservative, since the ball
lies on j's side of it. Rows are rebuilt every step from the other vehicles' latest positions.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from skyherd.safety.envelope import NZ, EnvelopeSpec, P, U, V


@dataclass(frozen=True)
class SeparationParams:
    radius_m: float = 1.0  # 3-D distance two vehicles' stopping points keep [m]

    def __post_init__(self) -> None:
        if not self.radius_m > 0:
            raise ValueError(f"separation.radius_m must be > 0, got {self.radius_m}")


def separation_rows(spec: EnvelopeSpec, p_k: np.ndarray, others: list[tuple[str, np.ndarray, np.ndarray]],
                    params: SeparationParams = SeparationParams()):  # fmt: skip
    """Rows (A (m, NZ), b (m,), names) of (S1) for vehicle k at p_k against `others`
    [(name, p_j (3,), v_j (3,))]."""
    m = len(others)
    if m == 0:
        return np.zeros((0, NZ)), np.zeros(0), ()
    pj = np.array([o[1] for o in others], dtype=float).reshape(m, 3)
    vj = np.array([o[2] for o in others], dtype=float).reshape(m, 3)
    A, b = _half_planes(spec, np.asarray(p_k, float) - pj, pj, vj, params.radius_m)
    return A, b, tuple(_name(params.radius_m, o[0]) for o in others)


def fleet_separation_rows(spec: EnvelopeSpec, positions: np.ndarray, velocities: np.ndarray,
                          names: list[str], params: SeparationParams = SeparationParams()):  # fmt: skip
    """`separation_rows` for every vehicle of a fleet against all the others at once, value
    for value the same: entry k is vehicle k's (A, b, names) against every j != k in order.
    positions, velocities (m, 3); one pass over all m × (m − 1) pairs instead of m passes."""
    p = np.asarray(positions, float).reshape(-1, 3)
    v = np.asarray(velocities, float).reshape(-1, 3)
    m = len(p)
    if m == 0:
        return []
    js = _others(m)  # js[i]: every j != i, in order
    pj = p[js]  # pair (i, j ∈ js[i]): d = p_i − p_j, vehicle j at p[j], v[j]
    A, b = _half_planes(spec, p[:, None, :] - pj, pj, v[js], params.radius_m)
    label = [_name(params.radius_m, x) for x in names]
    return [(A[i], b[i], tuple(label[:i] + label[i + 1 :])) for i in range(m)]  # = js[i]


def _half_planes(spec: EnvelopeSpec, d: np.ndarray, pj: np.ndarray, vj: np.ndarray,
                 radius_m: float) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(S1) for pairs along the leading axes: d = p_k − p_j (..., 3), p_j and v_j (..., 3) or
    broadcasting to it → A (..., NZ), b (...)."""
    dyn = spec.dynamics
    alpha = min(dyn.dt_s / dyn.tau_s, 1.0)
    T = spec.stop_times()[0]
    k = dyn.dt_s + T
    dist = np.sqrt(_sum3(d * d))
    near = dist <= 1e-6
    n = d / np.where(near, 1.0, dist)[..., None]
    n[near] = (0.0, 0.0, -1.0)  # on top of each other: push up
    # −n·p' − T n·v' <= −(r + n·p_j + T n·v_j) with p' = p + dt v', v' = (1−α) v + α u
    A = np.zeros((*d.shape[:-1], NZ))
    A[..., P] = -n
    A[..., V] = -k * (1 - alpha) * n
    A[..., U] = -k * alpha * n
    b = -(radius_m + _sum3(n * pj) + T * _sum3(n * vj))
    return A, b


def _sum3(x: np.ndarray) -> np.ndarray:
    """x.sum(axis=-1) for a last axis of 3, in its order (x0 + x1) + x2, without the reduction's
    per-row overhead. Equal value for value; only an all −0.0 row sums to −0.0, not +0.0,
    which the callers' +radius_m and sqrt do not tell apart."""
    return x[..., 0] + x[..., 1] + x[..., 2]


@lru_cache(maxsize=64)
def _others(m: int) -> np.ndarray:
    """(m, m − 1): row i lists 0..m−1 without i."""
    return np.array([[j for j in range(m) if j != i] for i in range(m)], dtype=np.intp).reshape(
        m, m - 1
    )


@lru_cache(maxsize=4096)
def _name(radius_m: float, other: str) -> str:
    return f"separation {radius_m:g} m from {other}"
