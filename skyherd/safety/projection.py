"""Minimal-intervention mode: the safe command closest to the proposed one.

    minimise  ||u - u0||^2   subject to   A_u u <= b - A_x x            (QP)

over the rows of the polyhedron selected for the current state (base rows, the inclusion
piece and the exclusion faces that the state is judged against). `qp_cvxpy` states the
problem readably (tests compare against it); `Projector` solves it in the loop with OSQP set up
once (sparsity fixed; unselected rows get an infinite bound) and updated per call (~25 µs,
against ~2 ms of cvxpy overhead). The solver works to a tolerance, so the bounds are
tightened by `tighten` and the answer is re-checked against the exact rows; a miss returns
None and the caller falls back.
"""

from __future__ import annotations

import numpy as np

from skyherd.safety.compiled import kernels
from skyherd.safety.envelope import NZ, Envelope, U

INF = 1e30


def qp_cvxpy(A_u: np.ndarray, h: np.ndarray, u0: np.ndarray) -> np.ndarray | None:
    """The QP stated with cvxpy: argmin ||u - u0||^2 s.t. A_u u <= h. None if infeasible."""
    import cvxpy as cp

    u = cp.Variable(A_u.shape[1])
    prob = cp.Problem(cp.Minimize(cp.sum_squares(u - u0)), [A_u @ u <= h])
    prob.solve(solver=cp.CLARABEL)
    if prob.status not in ("optimal", "optimal_inaccurate"):
        return None
    return np.asarray(u.value, float)


class Projector:
    """OSQP projection onto the command rows of one envelope (set up once, at the first
    projection the closed form does not answer: OSQP and the SciPy it needs are imported
    then, ~0.2 CPU s, not by every companion that never needs them)."""

    def __init__(self, envelope: Envelope, tighten: float = 1e-4, eps: float = 1e-5):
        self.envelope = envelope
        self.tighten = tighten
        Au = envelope.A[:, U]
        self.cmd_rows = np.flatnonzero(np.any(Au != 0, axis=1))  # rows the command can change
        self.state_rows = np.flatnonzero(~np.any(Au != 0, axis=1))
        self.A_u = np.ascontiguousarray(Au[self.cmd_rows])
        self.eps = eps
        self._solver = None  # OSQP, set up by solver() on first use
        self._z = np.zeros(NZ)

    def solver(self):
        """The OSQP problem over A_u (sparsity fixed; bounds and q updated per call)."""
        if self._solver is None:
            import osqp
            import scipy.sparse as sp

            k = len(self.cmd_rows)
            self._solver = osqp.OSQP()
            self._solver.setup(
                sp.csc_matrix(2.0 * np.eye(3)),
                np.zeros(3),
                sp.csc_matrix(self.A_u),
                -INF * np.ones(k),
                INF * np.ones(k),
                verbose=False,
                eps_abs=self.eps,
                eps_rel=self.eps,
                polishing=True,
                max_iter=4000,
                warm_starting=True,
                check_termination=5,  # test convergence every 5 iterations (default 25)
            )
        return self._solver

    def bounds(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
        """(A_u, h) of the selected polyhedron for state z[:8], and whether its state-only rows
        hold (if not, no command can make z safe)."""
        e = self.envelope
        zs = self._z
        zs[:] = z
        zs[U] = z[3:6]  # judge pieces and faces at 'keep the current velocity'
        r = e.A @ zs - e.b
        sel = kernels().select_mask(r, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
        state_ok = bool(np.all(r[self.state_rows] <= 0, where=sel[self.state_rows]))
        zs[U] = 0.0
        r0 = e.A[self.cmd_rows] @ zs - e.b[self.cmd_rows]  # A_x x - b
        h = np.where(sel[self.cmd_rows], -r0, INF)
        return self.A_u, h, state_ok

    def project(self, z: np.ndarray, closed_form: bool = True) -> np.ndarray | None:
        """Closest safe command to z[U] for the state in z, verified; None when there is none.

        closed_form: first try the projection onto each violated half-plane alone,
        u = u0 - (a·u0 - h) a / |a|^2; if one is feasible for every row it is the QP's optimum
        (the feasible set lies inside that half-plane). Otherwise, and when False, OSQP."""
        if not np.all(np.isfinite(z[:8])):
            return None
        u0 = z[U].copy()
        if not np.all(np.isfinite(u0)):
            u0 = np.zeros(3)  # NaN proposal: project 'hold' instead
        _, h, state_ok = self.bounds(z)
        if not state_ok:
            return None
        hb = np.where(h < INF, h - self.tighten, INF)
        if closed_form:
            u = self._single_row(u0, hb)
            if u is not None:
                zz = z.copy()
                zz[U] = u
                if self.envelope.worst(zz) <= 0.0:
                    return u
        # the extension object directly: the Python wrapper's bookkeeping costs ~30 µs a call
        ext = self.solver()._solver
        ext.update_data_vec(q=-2.0 * u0, l=None, u=hb)
        ext.solve()
        if ext.info.status_val not in (1, 2):  # solved, solved inaccurate
            return None
        u = np.array(ext.solution.x, float)
        zz = z.copy()
        zz[U] = u
        if not (np.all(np.isfinite(u)) and self.envelope.worst(zz) <= 0.0):
            return None
        return u

    def _single_row(self, u0: np.ndarray, hb: np.ndarray) -> np.ndarray | None:
        r = self.A_u @ u0 - hb
        bad = np.flatnonzero(r > 0)
        for i in bad[np.argsort(-r[bad])][:4]:
            a = self.A_u[i]
            u = u0 - r[i] / float(a @ a) * a
            if np.all(self.A_u @ u <= hb + 1e-12):
                return u
        return None
