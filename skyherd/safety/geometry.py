"""Plane geometry for fences: polygons as half-planes, convex decomposition, circle polygons.

Points are (north, east) [m] in the local NED frame about home, shape (n, 2).
A half-plane is (normal (2,), offset d): inside when normal · p <= d, with |normal| = 1 so
that normal · p - d is the signed distance [m] beyond the edge.
"""

from __future__ import annotations

import math

import numpy as np


def signed_area(poly: np.ndarray) -> float:
    """Shoelace area [m^2]; its sign gives the winding in the (north, east) plane."""
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(np.roll(x, -1), y))


def _cross(o: np.ndarray, a: np.ndarray, b: np.ndarray) -> float:
    return float((a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0]))


def validate_polygon(poly: np.ndarray, what: str) -> np.ndarray:
    """Check a polygon is (n >= 3, 2), finite, with non-zero area and no self-crossing edges."""
    p = np.asarray(poly, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 3:
        raise ValueError(f"{what}: need at least 3 (north, east) points, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{what}: non-finite coordinates")
    if np.allclose(p[0], p[-1]) and p.shape[0] > 3:
        p = p[:-1]  # closed ring given: drop the repeated first point
    if abs(signed_area(p)) < 1e-6:
        raise ValueError(f"{what}: zero area")
    n = len(p)
    for i in range(n):
        a1, a2 = p[i], p[(i + 1) % n]
        for j in range(i + 2, n):
            if (j + 1) % n == i:
                continue
            b1, b2 = p[j], p[(j + 1) % n]
            if _segments_cross(a1, a2, b1, b2):
                raise ValueError(f"{what}: edges {i} and {j} cross (self-intersecting polygon)")
    return p


def _segments_cross(a1, a2, b1, b2) -> bool:
    d1, d2 = _cross(b1, b2, a1), _cross(b1, b2, a2)
    d3, d4 = _cross(a1, a2, b1), _cross(a1, a2, b2)
    return (d1 * d2 < 0) and (d3 * d4 < 0)


def is_convex(poly: np.ndarray) -> bool:
    """True when every turn has the same sign (collinear points allowed)."""
    n = len(poly)
    signs = set()
    for i in range(n):
        c = _cross(poly[i], poly[(i + 1) % n], poly[(i + 2) % n])
        if abs(c) > 1e-9:
            signs.add(c > 0)
    return len(signs) <= 1


def half_planes(poly: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Convex polygon → outward unit normals N (n, 2) and offsets d (n,): inside ⇔ N p <= d."""
    ccw = signed_area(poly) > 0
    a, b = poly, np.roll(poly, -1, axis=0)
    e = b - a
    # outward normal of edge a→b: rotate the edge by -90° for a counter-clockwise ring
    nrm = np.stack([e[:, 1], -e[:, 0]], axis=1) if ccw else np.stack([-e[:, 1], e[:, 0]], axis=1)
    length = np.linalg.norm(nrm, axis=1)
    keep = length > 1e-9
    nrm = nrm[keep] / length[keep, None]
    d = np.einsum("ij,ij->i", nrm, a[keep])
    return nrm, d


def outer_edges(piece: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """For each edge that half_planes(piece) keeps: is it an edge of the original polygon
    (True) or a diagonal the decomposition added (False)? Shape (n_kept,)."""
    a, b = piece, np.roll(piece, -1, axis=0)
    keep = np.linalg.norm(b - a, axis=1) > 1e-9
    pa, pb = poly, np.roll(poly, -1, axis=0)
    out = []
    for u, v in zip(a[keep], b[keep]):
        fwd = np.all(np.isclose(pa, u), axis=1) & np.all(np.isclose(pb, v), axis=1)
        bwd = np.all(np.isclose(pa, v), axis=1) & np.all(np.isclose(pb, u), axis=1)
        out.append(bool(np.any(fwd | bwd)))
    return np.array(out, dtype=bool)


def convex_pieces(poly: np.ndarray) -> list[np.ndarray]:
    """Split a simple polygon into convex pieces: ear clipping, then Hertel–Mehlhorn merging.

    Hertel & Mehlhorn (1983): drop triangulation diagonals whose removal keeps both sides
    convex; the result has at most 4× the minimum number of convex pieces.
    """
    poly = np.asarray(poly, dtype=float)
    if is_convex(poly):
        return [poly]
    ring = poly if signed_area(poly) > 0 else poly[::-1]
    pieces = [list(t) for t in _ear_clip(ring)]
    merged = True
    while merged:
        merged = False
        for i in range(len(pieces)):
            for j in range(i + 1, len(pieces)):
                m = _merge(pieces[i], pieces[j])
                if m is not None and is_convex(ring[m]):
                    pieces[i] = m
                    del pieces[j]
                    merged = True
                    break
            if merged:
                break
    return [ring[p] for p in pieces]


def _ear_clip(ring: np.ndarray) -> list[tuple[int, int, int]]:
    """Triangles (vertex indices) of a counter-clockwise simple polygon."""
    idx = list(range(len(ring)))
    tris: list[tuple[int, int, int]] = []
    guard = 0
    while len(idx) > 3 and guard < 10_000:
        guard += 1
        for k in range(len(idx)):
            i0, i1, i2 = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            a, b, c = ring[i0], ring[i1], ring[i2]
            if _cross(a, b, c) <= 1e-12:
                continue  # reflex or degenerate corner
            if any(_in_triangle(ring[j], a, b, c) for j in idx if j not in (i0, i1, i2)):
                continue
            tris.append((i0, i1, i2))
            del idx[k]
            break
        else:
            raise ValueError("polygon could not be triangulated (self-intersecting?)")
    tris.append(tuple(idx))  # type: ignore[arg-type]
    return tris


def _in_triangle(p, a, b, c) -> bool:
    return _cross(a, b, p) >= 0 and _cross(b, c, p) >= 0 and _cross(c, a, p) >= 0


def _merge(p: list[int], q: list[int]) -> list[int] | None:
    """Merge two index rings sharing one edge (u, v) in p and (v, u) in q, else None."""
    n, m = len(p), len(q)
    for i in range(n):
        u, v = p[i], p[(i + 1) % n]
        for j in range(m):
            if q[j] == v and q[(j + 1) % m] == u:
                # p: ... u v ...; q: ... v u ...; walk p from v round to u, then q's rest.
                out = [p[(i + 1 + k) % n] for k in range(n)]  # starts at v, ends at u
                out += [q[(j + 2 + k) % m] for k in range(m - 2)]  # q after u, before v
                return out
    return None


def circle_polygon(center: np.ndarray, radius: float, sides: int, outer: bool) -> np.ndarray:
    """Regular polygon approximating a circle: `outer` circumscribes it (edges tangent),
    otherwise it is inscribed (vertices on the circle). Shape (sides, 2)."""
    if sides < 3:
        raise ValueError(f"a circle polygon needs at least 3 sides, got {sides}")
    r = radius / math.cos(math.pi / sides) if outer else radius
    ang = 2 * math.pi * np.arange(sides) / sides
    return np.asarray(center, float) + r * np.stack([np.cos(ang), np.sin(ang)], axis=1)


def point_in_polygon(p: np.ndarray, poly: np.ndarray) -> bool:
    """Even-odd rule; for tests and for checking decompositions."""
    x, y = p
    inside = False
    n = len(poly)
    for i in range(n):
        x1, y1 = poly[i]
        x2, y2 = poly[(i + 1) % n]
        if (y1 > y) != (y2 > y):
            xc = x1 + (y - y1) * (x2 - x1) / (y2 - y1)
            if x < xc:
                inside = not inside
    return inside
