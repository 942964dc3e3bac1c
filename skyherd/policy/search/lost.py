"""The classical search for a lost UGV, the documented baseline of issue 29 item 4.

Onboard, each UGV is identified by its marker's colour and located on the ground by
back-projecting its detection at the known altitude (on the GroundAir env's level camera that
is the UGV's ground position). `Tracker` keeps, per UGV, the last position it was seen at and
a velocity estimate (an exponential average of the finite differences between sightings):
its dead-reckoned position τ seconds after it was last seen is p + v·τ.

`LostSearch.act` returns the base policy's action while every UGV that was ever seen is in
view. When one is lost:

1. **go and widen**: the target is the centre of the smallest circle around the UGVs in view
   and the lost ones' dead-reckoned positions; the altitude is the one whose footprint holds
   that circle plus the prediction's uncertainty (σ0 + k_σ·τ), limited to the ceiling less a
   margin. When even the ceiling cannot hold them all, the lost UGV alone is the target, at
   the ceiling.
2. **expanding square**: once over the prediction at the wanted altitude and still not seen,
   legs of length leg_m, leg_m, 2 leg_m, 2 leg_m, 3 leg_m … (north, east, south, west …) around
   the dead-reckoned point, leg_m = the footprint's smaller half-side at that altitude.

Its commands are velocities (north, east, down) [m/s], not the policy's discrete 4 m/s actions:
horizontally k_h·(distance to the target) toward it, vertically k_v·(altitude error), each
within 90 % of the ground-air envelope's speed, climb and descent rows (8, 3, 2 m/s: the same
constraint set the net certifies against; safety/envelopes/quadrotor_groundair.toml). Climbing
and flying on at once is what widens the view fast enough: the speed-off UGV runs at 6 m/s,
faster than the policy's 4 m/s steps.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.task.fastphi import min_circle
from skyherd.task.params import TaskParams


@dataclass(frozen=True)
class SearchParams:
    """The search's knobs (SI)."""

    ceiling_margin_m: float = (
        6.0  # climb at most to the ceiling less this: the net brakes a 2.7 m/s climb in 5.2 m [m]
    )
    sigma0_m: float = 2.0  # the prediction's uncertainty when it was lost [m]
    sigma_rate_mps: float = 0.5  # and its growth per second since [m/s]
    frame_fill: float = (
        0.8  # the circle fills this fraction of the footprint's smaller half-side [-]
    )
    velocity_gain: float = 0.7  # weight of a new finite difference in the velocity estimate [-]
    arrive_m: float = 4.0  # over the prediction within this distance: start the square [m]
    k_h: float = 1.0  # horizontal gain [1/s]
    k_v: float = 0.5  # vertical gain [1/s]
    limit_fraction: float = 0.9  # of the envelope's speed, climb and descent rows [-]


@dataclass
class Track:
    pos: np.ndarray  # last seen (north, east) [m]
    t: float  # when [s]
    vel: np.ndarray = field(default_factory=lambda: np.zeros(2))  # [m/s]

    def predict(self, t: float) -> np.ndarray:
        return self.pos + self.vel * (t - self.t)


class Tracker:
    """Last sighting and velocity of each UGV (by identity)."""

    def __init__(self, p: SearchParams):
        self.p = p
        self.tracks: dict[int, Track] = {}

    def update(self, t: float, seen: dict[int, np.ndarray]) -> None:
        for i, pos in seen.items():
            pos = np.asarray(pos, dtype=float)
            tr = self.tracks.get(i)
            if tr is None:
                self.tracks[i] = Track(pos.copy(), t)
                continue
            dt = t - tr.t
            if dt > 1e-9:
                g = self.p.velocity_gain
                tr.vel = (1 - g) * tr.vel + g * (pos - tr.pos) / dt
            tr.pos, tr.t = pos.copy(), t


def footprint_half_m(alt_m: float, task: TaskParams) -> float:
    """The smaller half-side of the level camera's ground footprint at alt_m [m]."""
    c = task.camera
    fx = 0.5 * c.width_px / math.tan(0.5 * c.hfov_rad)
    z = alt_m - c.mount_offset_frd[2]
    return 0.5 * min(c.width_px, c.height_px) * z / fx


def altitude_for(radius_m: float, task: TaskParams, fill: float) -> float:
    """The altitude whose footprint's smaller half-side is radius_m / fill [m]."""
    c = task.camera
    fx = 0.5 * c.width_px / math.tan(0.5 * c.hfov_rad)
    return radius_m / fill * fx / (0.5 * min(c.width_px, c.height_px)) + c.mount_offset_frd[2]


def expanding_square(k: int, leg_m: float) -> np.ndarray:
    """The k-th corner (k ≥ 1) of an expanding square about the origin, legs 1, 1, 2, 2, 3, …
    times leg_m, turning north → east → south → west (north, east) [m]."""
    dirs = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
    p = np.zeros(2)
    for j in range(k):
        p = p + dirs[j % 4] * leg_m * (j // 2 + 1)
    return p


def envelope_speeds(fraction: float) -> tuple[float, float, float]:
    """(horizontal, climb, descent) [m/s]: `fraction` of the ground-air envelope's rows."""
    from skyherd.safety.config import ENVELOPE_DIR, load_envelope

    lim = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")[0].limits
    return fraction * lim.speed_h_mps, fraction * lim.climb_mps, fraction * lim.descent_mps


def velocity_to(uav_ned: np.ndarray, target_ne: np.ndarray, target_alt: float, p: SearchParams,
                speeds: tuple[float, float, float], v_ff=(0.0, 0.0)) -> np.ndarray:  # fmt: skip
    """(north, east, down) [m/s] toward the target (moving at v_ff [m/s]: fed forward, so a
    moving target is met without a lag), within `speeds`."""
    d = np.asarray(target_ne, dtype=float) - uav_ned[:2]
    vh = np.asarray(v_ff, dtype=float) + p.k_h * d
    n = float(np.hypot(*vh))
    if n > speeds[0]:
        vh *= speeds[0] / n
    vd = float(np.clip(p.k_v * (-target_alt - uav_ned[2]), -speeds[1], speeds[2]))
    return np.array([vh[0], vh[1], vd])


class LostSearch:
    """The base policy while all are in view; the search while one is lost (module docstring).

    `act(obs, t, uav_ned, seen)`: obs the policy observation, t [s], uav_ned (3,) the UAV's own
    position, seen {ugv id: (north, east)} the UGVs in view now. `mode` says what it did."""

    name = "search"

    def __init__(self, base: Callable[[np.ndarray], int], task: TaskParams | None = None,
                 p: SearchParams | None = None):  # fmt: skip
        self.base = base
        self.task = task if task is not None else TaskParams()
        self.p = p if p is not None else SearchParams()
        self.tracker = Tracker(self.p)
        self.mode = "base"
        self.square: tuple[np.ndarray, float, int] | None = None  # (origin, leg, corner k)
        self.quarry: int | None = None  # the UGV searched for
        self.speeds = envelope_speeds(self.p.limit_fraction)

    def act(self, obs: np.ndarray, t: float, uav_ned: np.ndarray,
            seen: dict[int, np.ndarray]) -> int | np.ndarray:  # fmt: skip
        """The base policy's discrete action, or the search's velocity command (3,) [m/s]."""
        cmd = self.search_command(t, uav_ned, seen)
        return int(self.base(obs)) if cmd is None else cmd

    def search_command(
        self, t: float, uav_ned: np.ndarray, seen: dict[int, np.ndarray]
    ) -> np.ndarray | None:
        """The search's velocity command (3,) [m/s], or None while every UGV ever seen is in
        view (the base pilot flies)."""
        self.tracker.update(t, seen)
        lost = [i for i in self.tracker.tracks if i not in seen]
        if self.quarry in seen:  # found: the search ends (others still lost start a new one)
            self.quarry, self.square = None, None
        if not lost:
            self.mode = "base"
            return None
        p, task = self.p, self.task
        ceiling = task.uav.alt_max_m - p.ceiling_margin_m
        if self.quarry not in lost:  # the search is for the first UGV lost, until it is found
            self.quarry = min(lost, key=lambda i: self.tracker.tracks[i].t)
        i_lost = self.quarry
        pred = {i: self.tracker.tracks[i].predict(t) for i in lost}
        sigma = max(p.sigma0_m + p.sigma_rate_mps * (t - self.tracker.tracks[i].t) for i in lost)
        pts = [tuple(x) for x in seen.values()] + [tuple(x) for x in pred.values()]
        cn, ce, r = min_circle(pts)
        alt = altitude_for(r + sigma, task, p.frame_fill)
        target, v_ff = np.array([cn, ce]), np.zeros(2)
        if alt > ceiling:  # the ceiling cannot hold them all: the lost one alone
            target, alt = pred[i_lost], ceiling
            v_ff = self.tracker.tracks[i_lost].vel
            self.mode = "go to the lost UGV"
        else:
            self.mode = "go and widen"
        alt = max(alt, task.uav.alt_min_m + 1.0)
        over = float(np.hypot(*(target - uav_ned[:2]))) < p.arrive_m and abs(alt + uav_ned[2]) < 2.0
        if self.square is not None or (over and alt >= ceiling - 1e-9):
            if self.square is None:
                self.square = (pred[i_lost], footprint_half_m(ceiling, task), 1)
            origin, leg, k = self.square
            origin = pred[i_lost]  # the square moves with the dead-reckoned point
            corner = origin + expanding_square(k, leg)
            if float(np.hypot(*(corner - uav_ned[:2]))) < p.arrive_m:
                k += 1
                corner = origin + expanding_square(k, leg)
            self.square = (origin, leg, k)
            target, alt, v_ff = corner, ceiling, self.tracker.tracks[i_lost].vel
            self.mode = f"expanding square, corner {k}"
        return velocity_to(uav_ned, target, alt, p, self.speeds, v_ff)
