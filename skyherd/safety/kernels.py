"""Compiled inner loop of the monitor: the union-of-polyhedra test of safety.envelope.

One pass over the rows of A (m, NZ), no allocation besides r; ~1 µs per call here, where the
same test in numpy (matvec + reduceat + max) costs ~6 µs of call overheads.
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True)
def _best_piece(r, n_base, n_piece_end, piece_starts):  # pragma: no cover
    """The convex fence piece the point is most inside: (its worst residual, first row, end row).
    The fence is the union of the pieces, so this piece is the one that judges the point."""
    npc = piece_starts.shape[0]
    best, bs, be = np.inf, 0, 0
    for k in range(npc):
        s0 = n_base + piece_starts[k]
        e0 = n_base + piece_starts[k + 1] if k + 1 < npc else n_piece_end
        pm = -np.inf
        for i in range(s0, e0):
            if r[i] > pm:
                pm = r[i]
        if pm < best:
            best, bs, be = pm, s0, e0
    return best, bs, be


@numba.njit(cache=True)
def worst_residual(A, b, z, n_base, n_piece_end, piece_starts, zone_starts):  # pragma: no cover
    """max( max_base r, min_pieces max_piece r, max_zones min_zone r ) with r = A z - b.

    <= 0: z is inside the envelope. NaN when z (or A z) is not finite.
    """
    m, nz = A.shape
    r = np.empty(m)
    for i in range(m):
        s = -b[i]
        for j in range(nz):
            s += A[i, j] * z[j]
        if not np.isfinite(s):
            return np.nan
        r[i] = s
    w = -np.inf
    for i in range(n_base):
        if r[i] > w:
            w = r[i]
    if piece_starts.shape[0] > 0:
        best, _, _ = _best_piece(r, n_base, n_piece_end, piece_starts)
        if best > w:
            w = best
    nzn = zone_starts.shape[0]
    for k in range(nzn):
        s0 = n_piece_end + zone_starts[k]
        e0 = n_piece_end + zone_starts[k + 1] if k + 1 < nzn else m
        zm = np.inf
        for i in range(s0, e0):
            if r[i] < zm:
                zm = r[i]
        if zm > w:
            w = zm
    return w


@numba.njit(cache=True)
def select_mask(r, n_base, n_piece_end, piece_starts, zone_starts):  # pragma: no cover
    """Rows of the polyhedron r is judged against (the Envelope.select rule) as a mask (m,)."""
    m = r.shape[0]
    sel = np.zeros(m, dtype=np.bool_)
    for i in range(n_base):
        sel[i] = True
    if piece_starts.shape[0] > 0:
        _, bs, be = _best_piece(r, n_base, n_piece_end, piece_starts)
        for i in range(bs, be):
            sel[i] = True
    nzn = zone_starts.shape[0]
    for k in range(nzn):
        s0 = n_piece_end + zone_starts[k]
        e0 = n_piece_end + zone_starts[k + 1] if k + 1 < nzn else m
        zm, zi = np.inf, s0
        for i in range(s0, e0):
            if r[i] < zm:
                zm, zi = r[i], i
        sel[zi] = True
    return sel


@numba.njit(cache=True)
def nearest_active(
    A, b, z, near, n_base, n_piece_end, piece_starts, zone_starts
):  # pragma: no cover
    """Index of the row with the largest residual r_i > -near_i in the polyhedron z is judged
    against (the Envelope.select rule), or -1 when no row is nearly active."""
    m, nz = A.shape
    r = np.empty(m)
    for i in range(m):
        s = -b[i]
        for j in range(nz):
            s += A[i, j] * z[j]
        r[i] = s
    sel = select_mask(r, n_base, n_piece_end, piece_starts, zone_starts)
    best, bi = -np.inf, -1
    for i in range(m):
        if sel[i] and r[i] > -near[i] and r[i] + near[i] > best:
            best, bi = r[i] + near[i], i
    return bi
