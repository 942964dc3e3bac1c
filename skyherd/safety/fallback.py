"""What flies the vehicle when the AI may not: the airframe's fallback and the recovery PID.

All commands are velocity setpoints (NED, m/s), optionally with a position to hold.
- HoverFallback (multirotor): brake to zero velocity, then hold where it stopped.
- LoiterFallback (fixed-wing): circle at the current altitude, radius R = v^2 / (g tan φmax),
  centred on the side of the track with more room inside the fence.
- RecoveryPID: a PID on position error → velocity command that brings the vehicle to the
  nearest point inside the fence with a margin; speed- and rate-limited to the envelope.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.safety.envelope import NZ, Envelope, Kind, P
from skyherd.safety.nearest import nearest_point

ZERO3 = np.zeros(3)


def norm(v: np.ndarray) -> float:
    """np.linalg.norm(v) of a vector: sqrt(v·v), numpy's own formula (the same dot, so the
    same bits), without its argument handling (µs on a 3-vector)."""
    a = np.asarray(v, float)
    return math.sqrt(a.dot(a))


class HoverFallback:
    """Multirotor: brake (velocity setpoint 0) until slower than `settle_mps`, then hold there."""

    def __init__(self, settle_mps: float = 0.5):
        self.settle_mps = settle_mps
        self.hold_pos: np.ndarray | None = None

    def engage(self, state: VehicleState) -> None:
        self.hold_pos = None

    def command(self, state: VehicleState) -> Setpoint:
        if self.hold_pos is None and norm(state.vel_ned) < self.settle_mps:
            self.hold_pos = np.array(state.pos_ned, float)
        if self.hold_pos is None:
            return Setpoint(vel_ned=ZERO3.copy())
        return Setpoint(pos_ned=self.hold_pos.copy(), vel_ned=ZERO3.copy())

    def settled(self, state: VehicleState) -> bool:
        return self.hold_pos is not None


class LoiterFallback:
    """Fixed-wing: circle of radius R = v^2/(g tan bank_max) at the altitude of engagement.

    Guidance: a vector field toward the circle (tangent + radial correction), Lawrence et al.
    (2008) style, flown at the engagement speed (at least `min_speed_mps`).
    """

    def __init__(
        self,
        bank_max_rad: float,
        geometry: Envelope,
        min_speed_mps: float,
        k_radial: float = 1.5,
    ):
        self.bank_max = bank_max_rad
        self.geometry = geometry
        self.min_speed = min_speed_mps
        self.k_radial = k_radial
        self.center: np.ndarray | None = None
        self.radius = 0.0
        self.speed = min_speed_mps
        self.alt_down = 0.0
        self.direction = 1.0  # +1 clockwise seen from above (turn right), -1 left

    def engage(self, state: VehicleState) -> None:
        v = state.vel_ned[:2]
        self.speed = max(float(np.hypot(*v)), self.min_speed)
        self.radius = self.speed**2 / (GRAVITY * math.tan(self.bank_max))
        heading = v / np.linalg.norm(v) if np.linalg.norm(v) > 1e-3 else np.array([1.0, 0.0])
        right = np.array([-heading[1], heading[0]])  # 90° clockwise of the track in (N, E)
        best = None
        for sgn in (1.0, -1.0):  # the side whose circle keeps the most room inside the fence
            c = state.pos_ned[:2] + sgn * self.radius * right
            ang = np.linspace(0, 2 * np.pi, 16, endpoint=False)
            pts = c + self.radius * np.stack([np.cos(ang), np.sin(ang)], 1)
            worst = max(
                self.geometry.distance_outside(np.array([p[0], p[1], state.pos_ned[2]]))
                for p in pts
            )
            if best is None or worst < best[0]:
                best = (worst, c, sgn)
        _, self.center, self.direction = best
        self.alt_down = float(state.pos_ned[2])

    def command(self, state: VehicleState) -> Setpoint:
        r = state.pos_ned[:2] - self.center
        d = float(np.linalg.norm(r)) or 1e-6
        radial = r / d
        tangent = self.direction * np.array([-radial[1], radial[0]])
        v = tangent - self.k_radial * (d - self.radius) / self.radius * radial
        v = self.speed * v / np.linalg.norm(v)
        vd = float(np.clip(0.5 * (self.alt_down - state.pos_ned[2]), -2.0, 2.0))
        return Setpoint(vel_ned=np.array([v[0], v[1], vd]))

    def settled(self, state: VehicleState) -> bool:
        """A loiter is steady from its start (the supervisor's hold_min_s paces the switch)."""
        return True


def row_margins(geometry: Envelope, margin_m: float) -> np.ndarray:
    """Per-row recovery margin (m,) [m]: `margin_m` for horizontal rows, at most 40 % of the
    floor-to-ceiling band for the altitude rows (a fixed-wing's horizontal margin can exceed
    the band)."""
    lim = geometry.spec.limits
    band = 0.4 * (lim.ceiling_m - lim.floor_m)
    return np.where(geometry.kinds == int(Kind.ALTITUDE), min(margin_m, band), margin_m)


def selected_rows(geometry: Envelope, pos_ned: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(row indices of the polyhedron pos_ned is judged against, residuals r (m,))."""
    z = np.zeros(NZ)
    z[P] = pos_ned
    r = geometry.residual(z)
    return geometry.selected(r), r


def inside_with_margin(geometry: Envelope, pos_ned: np.ndarray, margin_m: float) -> bool:
    """Every selected position row holds with its recovery margin (row_margins)."""
    sel, r = selected_rows(geometry, pos_ned)
    return bool((r[sel] <= -row_margins(geometry, margin_m)[sel]).all())


def recovery_target(geometry: Envelope, pos_ned: np.ndarray, margin_m: float) -> np.ndarray:
    """Nearest point to pos_ned (3,) inside the fence with a margin to every position row:

        minimise ||p - p0||^2  s.t.  A_p p <= b - m    (rows of the selected polyhedron,
                                                         m from row_margins)

    solved exactly (safety.nearest). Halves the margins until feasible (a small piece may not
    fit them); pos_ned itself if even 1/128 of them does not fit. NED [m]."""
    sel, _ = selected_rows(geometry, pos_ned)
    A = geometry.A[sel][:, P]
    b = geometry.b[sel]
    m = row_margins(geometry, margin_m)[sel]
    for _ in range(8):
        p = nearest_point(A, b - m, pos_ned)
        if p is not None and np.all(A @ p <= b - 0.5 * m):
            return p
        m = m * 0.5
    return np.asarray(pos_ned, float)


@dataclass(frozen=True)
class PidGains:
    """Position PID → velocity command. kp [1/s], ki [1/s^2], kd [-] (on velocity)."""

    kp: float = 0.6
    ki: float = 0.02
    kd: float = 0.2
    i_limit_m_s: float = 1.0  # anti-windup bound on ki·∫e [m/s]
    i_zone_m: float = 1.0  # integrate only this close to the target (no windup on the way) [m]


class RecoveryPID:
    """Brings the vehicle to a target inside the fence with margin.

    u = kp e + ki ∫e dt - kd v,  e = p_target - p; horizontal speed ≤ speed_mps, vertical within
    climb/descent, and |u - v| ≤ a_max·tau so the command respects the envelope's accel rows.
    """

    def __init__(
        self,
        gains: PidGains,
        geometry: Envelope,
        speed_mps: float,
        margin_m: float,
        min_speed_mps: float = 0.0,
    ):
        self.g = gains
        self.geometry = geometry
        lim, dyn = geometry.spec.limits, geometry.spec.dynamics
        self.speed = min(speed_mps, lim.speed_h_mps * 0.9)
        self.climb = lim.climb_mps * 0.9
        self.descent = lim.descent_mps * 0.9
        cosk = math.cos(math.pi / lim.speed_sides)
        a_h = min(lim.accel_h_mps2, GRAVITY * math.tan(lim.tilt_cmd_rad))
        self.dv_h = 0.9 * a_h * dyn.tau_s * cosk
        self.dv_v = 0.9 * lim.accel_v_mps2 * dyn.tau_s
        self.margin = margin_m
        self.min_speed = min(min_speed_mps, self.speed)  # a fixed-wing cannot fly slower
        # orbit radius about the target for a fixed-wing: 1.5 x its tightest turn at that speed
        bank = dyn.bank_max_rad
        self.orbit_radius = (
            1.5 * self.speed**2 / (GRAVITY * math.tan(bank))
            if bank > 0 and self.min_speed > 0
            else 0.0
        )
        self.target = np.zeros(3)
        self.integral = np.zeros(3)
        self.t_last: float | None = None

    def engage(self, state: VehicleState) -> None:
        self.target = recovery_target(self.geometry, state.pos_ned, self.margin)
        self.integral = np.zeros(3)
        self.t_last = None

    def error(self, state: VehicleState) -> float:
        return norm(self.target - state.pos_ned)

    def command(self, t: float, state: VehicleState) -> Setpoint:
        dt = 0.0 if self.t_last is None else max(t - self.t_last, 0.0)
        self.t_last = t
        e = self.target - state.pos_ned
        u = self.g.kp * e + self.integral - self.g.kd * state.vel_ned
        # saturate speed, then limit the step from the current velocity (accel rows)
        h = float(np.hypot(u[0], u[1]))
        sat = h > self.speed
        if sat:
            u[:2] *= self.speed / h
        if self.min_speed > 0 and float(np.hypot(e[0], e[1])) < self.orbit_radius:
            # a fixed-wing cannot stop on the target: orbit it (tangent + radial correction)
            sat = True
            r = -e[:2]
            d = float(np.hypot(r[0], r[1]))
            if d < 1.0:  # on the target: take the radial to the left of the track
                vh = state.vel_ned[:2]
                r = (
                    np.array([-vh[1], vh[0]])
                    if float(np.hypot(*vh)) > 0.1
                    else np.array([1.0, 0.0])
                )
                r = r / float(np.hypot(r[0], r[1]))
                d = 1.0
            rad = r / d
            w = (
                np.array([-rad[1], rad[0]])
                - 1.5 * (d - self.orbit_radius) / self.orbit_radius * rad
            )
            u[:2] = self.min_speed * w / np.linalg.norm(w)
        elif h < self.min_speed:
            sat = True
            u[:2] = u[:2] / h * self.min_speed if h > 1e-6 else state.vel_ned[:2]
        u[2] = min(max(u[2], -self.climb), self.descent)  # np.clip's value, NaN included
        du = u - state.vel_ned
        dh = float(np.hypot(du[0], du[1]))
        if dh > self.dv_h and self.min_speed == 0:  # multirotor: respect the accel rows
            du[:2] *= self.dv_h / dh  # (a fixed-wing turns at its own bank limit instead)
        if self.min_speed == 0:
            du[2] = min(max(du[2], -self.dv_v), self.dv_v)
        # A fixed-wing's vertical command is TECS's climb-rate demand, which TECS paces itself:
        # slewing it from the measured sink would turn "climb" into "descend" in a downdraft.
        u = state.vel_ned + du
        if not sat and norm(e) < self.g.i_zone_m:  # conditional integration
            self.integral = np.clip(
                self.integral + self.g.ki * e * dt, -self.g.i_limit_m_s, self.g.i_limit_m_s
            )
        return Setpoint(vel_ned=u, pos_ned=None)
