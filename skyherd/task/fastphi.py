"""φ(s) on the fast path: a level downward camera over flat ground, in pure Python.

Same numbers as `perception.features.features_from_truth` for a level UAV with heading 0 (a unit
test checks them against it), about 10× faster: the point-model UAV never tilts, so projection is
u = fx·Δeast/z + cx, v = −fx·Δnorth/z + cy with depth z = altitude − lens offset, and the minimum
enclosing circle of ≤ 3 points has a closed form.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from skyherd.perception.camera import CameraParams

if TYPE_CHECKING:  # min_circle alone (world.team's start altitude in `skyherd fly`): no OpenCV
    from skyherd.perception.features import FeatureParams


def min_circle(pts: list[tuple[float, float]]) -> tuple[float, float, float]:
    """Minimum enclosing circle (cu, cv, r) of 1–3 points; more points fall back to Welzl-free O(n³)."""
    n = len(pts)
    if n == 1:
        return pts[0][0], pts[0][1], 0.0
    if n == 2:
        (a, b), (c, d) = pts
        return 0.5 * (a + c), 0.5 * (b + d), 0.5 * math.hypot(a - c, b - d)
    best = None
    # circles on each pair's diameter, then circumcircles of triples: the smallest enclosing one
    for i in range(n):
        for j in range(i + 1, n):
            cu, cv = 0.5 * (pts[i][0] + pts[j][0]), 0.5 * (pts[i][1] + pts[j][1])
            r = 0.5 * math.hypot(pts[i][0] - pts[j][0], pts[i][1] - pts[j][1])
            if (best is None or r < best[2]) and _encloses(pts, cu, cv, r):
                best = (cu, cv, r)
    for i in range(n):
        for j in range(i + 1, n):
            for k in range(j + 1, n):
                c = _circumcircle(pts[i], pts[j], pts[k])
                if c is not None and (best is None or c[2] < best[2]) and _encloses(pts, *c):
                    best = c
    return best


def _encloses(pts, cu, cv, r) -> bool:
    r2 = (r * (1 + 1e-9) + 1e-9) ** 2
    return all((p[0] - cu) ** 2 + (p[1] - cv) ** 2 <= r2 for p in pts)


def _circumcircle(p, q, s):
    ax, ay = p
    bx, by = q
    cx, cy = s
    d = 2.0 * (ax * (by - cy) + bx * (cy - ay) + cx * (ay - by))
    if abs(d) < 1e-12:
        return None
    a2, b2, c2 = ax * ax + ay * ay, bx * bx + by * by, cx * cx + cy * cy
    ux = (a2 * (by - cy) + b2 * (cy - ay) + c2 * (ay - by)) / d
    uy = (a2 * (cx - bx) + b2 * (ax - cx) + c2 * (bx - ax)) / d
    return ux, uy, math.hypot(ax - ux, ay - uy)


class LevelCamera:
    """Precomputed constants of a level, heading-0 downward camera."""

    def __init__(self, cam: CameraParams, fparams: FeatureParams | None = None):
        from skyherd.perception.features import FeatureParams

        fparams = fparams or FeatureParams()
        if cam.mount_pitch_rad != 0.0:
            raise ValueError("the fast path assumes a straight-down camera (mount_pitch_rad = 0)")
        self.cam = cam
        self.fx = cam.fx
        self.cx, self.cy = cam.cx, cam.cy
        self.W, self.H = cam.width_px, cam.height_px
        self.off_n, self.off_e, self.off_d = cam.mount_offset_frd
        self.half_diag = 0.5 * math.hypot(self.W, self.H)
        self.half_min = 0.5 * min(self.W, self.H)
        self.alt_max = fparams.altitude_max_m

    def pixels(
        self, n: float, e: float, alt: float, ugvs: list[tuple[float, float]], detectable=None
    ):
        """UGV (north, east) [m] → list of (u, v) [px] and seen flags, UAV at (n, e, alt).

        detectable: optional list of bools (False = camouflaged: a detector misses it).
        """
        z = alt - self.off_d  # lens depth above the ground [m]
        ln, le = n + self.off_n, e + self.off_e
        out, seen = [], []
        if z <= 1e-9:
            return [(math.nan, math.nan)] * len(ugvs), [False] * len(ugvs)
        k = self.fx / z
        hi_u, hi_v = self.W - 0.5, self.H - 0.5
        for un, ue in ugvs:
            u = k * (ue - le) + self.cx
            v = -k * (un - ln) + self.cy
            out.append((u, v))
            seen.append(-0.5 <= u <= hi_u and -0.5 <= v <= hi_v)
        if detectable is not None:
            seen = [s and d for s, d in zip(seen, detectable)]
        return out, seen

    def phi(self, n: float, e: float, alt: float, ugvs: list[tuple[float, float]], detectable=None):
        """φ(s) as a list of 8 floats (perception.features order) and (seen flags, radius [px])."""
        uv, seen = self.pixels(n, e, alt, ugvs, detectable)
        a = alt / self.alt_max
        a = 0.0 if not math.isfinite(a) else min(max(a, 0.0), 1.0)
        vis = [p for p, s in zip(uv, seen) if s]
        k = len(vis)
        if k == 0:
            return [0.5, 0.5, 0.0, a, 0.0, 0.0, 0.0, 1.0], seen, 0.0
        mu = sum(p[0] for p in vis) / k
        mv = sum(p[1] for p in vis) / k
        _, _, r = min_circle(vis)
        nexp = len(ugvs)
        edge = min(
            min(p[0] + 0.5, self.W - 0.5 - p[0], p[1] + 0.5, self.H - 0.5 - p[1]) for p in vis
        )
        phi = [
            min(max(0.5 + (mu - self.cx) / self.W, 0.0), 1.0),
            min(max(0.5 + (mv - self.cy) / self.H, 0.0), 1.0),
            min(r / self.half_diag, 1.0),
            a,
            min(k / nexp, 1.0),
            1.0 if k >= nexp else 0.0,
            min(max(edge / self.half_min, 0.0), 1.0),
            1.0,
        ]
        return phi, seen, r
