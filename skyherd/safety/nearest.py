"""The point of a polyhedron nearest to a given point, exactly: the safety net's one QP.

    minimise ||x - x0||^2   subject to   A x <= h,    x in R^n (n = 3 in the net)      (1)

The net asks it twice: the safe velocity command closest to the proposed one (projection.py,
rows of the selected polyhedron) and the recovery target, the point inside the fence nearest
the vehicle (fallback.py). Rows with h >= INF (1e30) are unselected and dropped; each kept row
is scaled to a unit normal, n_j·x <= c_j (n_j = a_j / |a_j|, c_j = h_j / |a_j|), so that a
residual n_j·x - c_j is the distance beyond plane j in the unit of x.

Method: Goldfarb and Idnani's dual active-set method (Math. Programming 27:1-33, 1983) with
the identity for Hessian, which makes it short. Start at the unconstrained minimum x = x0
with no active row. While some row is violated, take the most violated one, p, and walk
along the path that keeps the active rows' planes and the optimality condition

    x - x0 + sum_{i active} u_i n_i + u_p n_p = 0,    u >= 0                           (2)

while raising u_p from 0. Split n_p into its part in the span of the active normals and the
rest,

    n_p = sum_i r_i n_i + w,    w orthogonal to every active n_i                        (3)

then a step t moves x <- x - t w, u_i <- u_i - t r_i, u_p <- u_p + t, which keeps (2) and
the active planes, and lowers p's residual s_p by t |w|^2. The step stops at the first of
    t2 = s_p / |w|^2                    p reaches its plane: p joins the active rows;
    t1 = min_{r_i > 0} u_i / r_i        a multiplier reaches 0: row i leaves, p is tried again.
If neither exists (w = 0 and no r_i > 0) the set is empty: n_p = sum r_i n_i with r <= 0, so
every feasible y has n_p·y = sum r_i n_i·y >= sum r_i c_i = n_p·x > c_p, a contradiction.

Why the answer is exact, not within a solver's tolerance: at the end every row holds and (2)
holds with u >= 0, the optimality (KKT) conditions of the convex problem (1), so x is its
unique optimum. That optimum is the projection of x0 onto the affine hull of the active
planes, at most n of them and linearly independent (a row joins only when w != 0), so it is
computed once more from them in closed form (eq. 4 below) rather than kept from the walk.

Tolerances: a point is feasible when every residual is <= `tol` (default 1e-9, the unit of x);
a new normal within 1e-10 of the span of the active ones (|w| <= 1e-10) counts as dependent on
them (duplicate and parallel rows). A zero row 0·x <= h is dropped when h >= -tol and makes
the set empty otherwise. A NaN or infinite x0, NaN in h or in a kept row of A: None. A walk
not finished in 4 m + 8 steps (m rows) also returns None; the tests' 2,400 random problems need
at most 11, the net's at most 3.

Cost: the net's polyhedra have 43-44 selected command rows (projection; quadrotor, fixed-wing
and ground-air envelopes) and 23-24 position rows (recovery). On them the walk takes 1-3 steps
of a few µs each (bench_safety: ~26 µs a projection, OSQP set up once ~37 µs), where
enumerating every pair and triple of 44 rows would be ~14,000 candidate points a call.
"""

from __future__ import annotations

import math

import numpy as np

INF = 1e30  # an upper bound at or above INF is no bound (an unselected row)
DEPENDENT = 1e-10  # |w| at or below this: the new normal lies in the span of the active ones


def nearest_point(
    A: np.ndarray, h: np.ndarray, x0: np.ndarray, tol: float = 1e-9
) -> np.ndarray | None:
    """argmin ||x - x0|| over {x : A x <= h}, or None when that set is empty (or input NaN).

    A (m, n), h (m,), x0 (n,). Rows with h >= INF are ignored. Exact to rounding (module
    docstring); the result satisfies A x <= h + tol |a_j| row by row (to rounding)."""
    x0 = np.asarray(x0, float)
    h = np.asarray(h, float)
    keep = ~(h >= INF)  # NaN kept: it makes c, then s, NaN below
    A, h = np.asarray(A, float)[keep], h[keep]
    norm = np.sqrt(np.einsum("ij,ij->i", A, A))
    if not np.all(np.isfinite(norm)):
        return None  # NaN or infinite in a kept row of A
    if not norm.all():  # 0·x <= h: always true or never
        zero = norm == 0.0
        if (h[zero] < -tol).any():
            return None
        A, h, norm = A[~zero], h[~zero], norm[~zero]
    if not len(h):
        return x0.copy() if np.all(np.isfinite(x0)) else None
    N = A / norm[:, None]  # unit normals n_j
    c = h / norm  # n_j·x <= c_j
    s = N @ x0 - c  # residuals: the distances beyond each plane
    if not np.all(np.isfinite(s)):
        return None  # NaN or infinite in x0 or h (h = -inf: no x satisfies the row)

    x = x0
    active: list[int] = []  # rows on whose plane x lies, linearly independent
    u: list[float] = []  # their multipliers in (2), >= 0
    for _ in range(4 * len(c) + 8):  # each row joins at most a few times; a cap, never reached
        p = int(np.argmax(s))
        if s[p] <= tol:
            return polish(N, c, x0, active)
        up = 0.0  # p's multiplier, raised from 0
        while True:
            w, r = split(N[active], N[p])  # eq. (3)
            ww = float(w @ w)
            t2 = float(N[p] @ x - c[p]) / ww if ww > DEPENDENT**2 else math.inf
            t1, k = math.inf, -1
            for i, ri in enumerate(r):
                if ri > 0 and u[i] / ri < t1:
                    t1, k = u[i] / ri, i
            if t1 == math.inf and t2 == math.inf:
                return None  # n_p a non-positive combination of active normals: empty set
            t = min(t1, t2)
            x = x - t * w
            u = [ui - t * ri for ui, ri in zip(u, r)]
            up += t
            if t2 <= t1:  # p reaches its plane and joins
                active.append(p)
                u.append(up)
                break
            del active[k], u[k]  # row k's multiplier reached 0: it leaves; try p again
        s = N @ x - c
    return None


def gram_solve(Na: np.ndarray, v: np.ndarray) -> np.ndarray:
    """y = (Na Na^T)^-1 v for q = 1, 2 or 3 unit rows Na (q, d), linearly independent."""
    if len(Na) == 1:
        return v  # |n| = 1
    return np.linalg.solve(Na @ Na.T, v)


def split(Na: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray | tuple]:
    """n = Na^T r + w with w orthogonal to the rows of Na (q, d), q <= d independent (eq. 3):
    r = (Na Na^T)^-1 Na n, w = n - Na^T r; w = 0 when q = d (the rows span R^d; what the
    formula leaves there is rounding, amplified by the rows' conditioning)."""
    if not len(Na):
        return n, ()
    r = gram_solve(Na, Na @ n)
    if len(Na) == len(n):
        return np.zeros_like(n), r
    return n - Na.T @ r, r


def polish(N: np.ndarray, c: np.ndarray, x0: np.ndarray, active: list[int]) -> np.ndarray:
    """The projection of x0 onto the affine hull of the active planes:

    x = x0 - Na^T (Na Na^T)^-1 (Na x0 - c_a)                                            (4)
    """
    if not active:
        return x0.copy()
    if len(active) == 1:  # the one plane's: x0 - n (n·x0 - c)
        n = N[active[0]]
        return x0 - (n @ x0 - c[active[0]]) * n
    Na = N[active]
    return x0 - Na.T @ gram_solve(Na, Na @ x0 - c[active])
