"""Drills: an adversarial scripted "AI" flies a real autopilot in SITL behind the supervisor.

Each drill hands a vehicle in OFFBOARD to a scripted AI that behaves, attacks (pushes at a
fence, NaN, stalls, a lost camera or link ...) and behaves again. The supervisor sits between
them; its FALLBACK is the autopilot's own HOLD. Ground truth (the simulated vehicle) is
checked against the position-only envelope at every autopilot step.

A drill passes when (1) the vehicle never went beyond the fence by more than the set's
`breach_tolerance_m`, (2) the supervisor caught the attack it was meant to catch (reason
containing the drill's keyword), and (3) the AI was flying again at the end. A drill judged
on (3) runs at least `recovery_allowance_s` after its attack ends (derived from the airframe:
least fallback, a half turn back for a fixed-wing, the recovery margin, the hysteresis).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.autopilot_api import Autopilot, FlightMode, Setpoint
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.safety.envelope import Dynamics, EnvelopeSpec
from skyherd.safety.judge import (
    Check,
    Ending,
    Expect,
    JudgeParams,
    ModeChange,
    NetRecord,
    Truth,
    clearances,
    first_failed,
    judge,
    own_flight,
    verdict,
)
from skyherd.safety.net import SafetyNet, apply_decision
from skyherd.safety.supervisor import Mode, Supervisor, SupervisorParams

Act = Callable[[float, VehicleState], Setpoint | None]


VERTICAL_ATTACK_END_S = 12.0  # the scripted ceiling / floor attacks end after this [s]
START_CLEARANCE_M = 12.0  # a random drill starts at least this far inside its boundary [m]


@dataclass(frozen=True)
class DrillParams:
    """Harness settings (saved with each run)."""

    policy_dt_s: float = Dynamics.dt_s  # AI + supervisor period [s]: the envelope's control period
    takeoff_alt_m: float = 20.0
    duration_s: float = 35.0  # AI time per multirotor drill after hand-over [s]
    duration_fixedwing_s: float = 90.0  # a fixed-wing needs longer: loiter, turn back, recover [s]
    fixedwing_speed_mps: float = 24.0  # airspeed the fixed-wing starts with [m/s]
    settle_timeout_s: float = 40.0  # reaching the start point [s]
    slew_h_mps: float = 1.2  # a well-behaved AI changes its command at most this per tick [m/s]
    slew_v_mps: float = 1.0
    lead_max_rad: float = 0.35  # a well-behaved fixed-wing AI leads its course by at most this
    behave_climb_mps: float = 1.0  # ... climbs or sinks toward its altitude at most this [m/s]
    behave_vz_step_mps: float = 4.0  # ... and its climb demand differs from the measured climb
    # by at most this [m/s] (the fixed-wing set's vertical accel row: 1.5 m/s2 x tau 3 s = 4.5).
    # TECS paces the demand itself: slewed 1 m/s from the measured climb (slew_v_mps), a gust
    # or TECS's speed-to-height exchange made the AI ask for more than the climb/descent row.
    use_autopilot_hold: bool = True  # FALLBACK = the autopilot's own HOLD mode

    def duration(self, airframe: str) -> float:
        return self.duration_fixedwing_s if airframe == "fixedwing" else self.duration_s


@dataclass
class Script:
    """One drill's scripted AI: `attack` runs in [t_on, t_off) after hand-over, `behave`
    otherwise; `camera_ok` / `link_ok` script the inputs' health."""

    name: str
    start_ned: np.ndarray
    attack: Act
    t_on: float
    t_off: float
    expect: tuple[str, ...]  # one of these must appear in a fallback reason ("" = any or none)
    behave_target: np.ndarray | None = None
    camera_ok: Callable[[float], bool] = lambda t: True
    link_ok: Callable[[float], bool] = lambda t: True
    must_trigger: bool = True
    start_heading: float = 0.0  # fixed-wing: initial course [rad]
    duration_s: float | None = None  # AI time after hand-over [s]; None = DrillParams default
    behave: Act | None = None  # default: fly back toward the start point
    # --- adversarial faults (safety.campaign); times relative to the hand-over [s]
    air_start: bool = False  # the vehicle starts at start_ned in the air (no take-off)
    handover_s: float = 0.0  # absolute sim time of the hand-over when air_start (fault times)
    link_cut: tuple[float, float] | None = None  # both directions cut in [a, b): no commands,
    # no telemetry, no heartbeats (the net sees the last state; the autopilot its own failsafe)
    params: tuple[tuple[float, str, float | None], ...] = ()  # (t, name, value): a client's
    # PARAM_SET; value None = a client sets it back to the value before the first PARAM_SET.
    # After such a restore the net must re-check and hand back to the AI (unless it yielded).
    expect_yield: bool = False  # the autopilot's failsafe must take over (and is not undone)
    kind: str = ""
    after_yield_s: float = 15.0  # keep judging this long after the net yielded, then stop
    must_recover: bool = True  # the AI must be flying again at the end

    def act(self, tr: float, s: VehicleState, p: DrillParams) -> Setpoint | None:
        """The scripted AI's proposal at tr [s after the hand-over]: `attack` in [t_on, t_off),
        `behave` otherwise (default: back toward the start point, or `behave_target`). The one
        rule every drill flies by: in-process, through MAVLink, and as `skyherd fly`'s pilot
        (mission.pilots.DrillPilot)."""
        if self.t_on <= tr < self.t_off:
            return self.attack(tr, s)
        if self.behave is not None:
            return self.behave(tr, s)
        target = self.start_ned if self.behave_target is None else self.behave_target
        return toward(target, 3.0, 1.0, p)(tr, s)


@dataclass
class DrillResult:
    name: str
    airframe: str
    passed: bool
    excursion_m: float  # worst ground-truth distance beyond the fence (<= 0: stayed inside)
    fallback_s: float
    pid_s: float
    recover_s: float  # first fallback → AI flying again [s] (nan: never triggered / recovered)
    rejected: int
    projected: int
    switches: int
    reasons: list[str]
    why: str  # why it failed ("" if passed)
    track: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    kind: str = ""
    overridden: int = 0  # times the net switched the autopilot out of a mode it chose itself
    yielded: str = ""  # the mode the net yielded to ("" = never)
    min_clearance_m: float = math.nan  # ground truth: smallest distance inside the fence [m]
    autopilot_excursion_m: float = -math.inf  # worst, in the autopilot's own flight after a yield
    autopilot_excursion_mode: str = ""  # the autopilot's mode at that worst point (HOLD, RTL ...)
    restored: str = ""  # after a client restored a sabotaged parameter: "handed back" (the net
    # re-checked and the AI flew again), "waiting (yielded to X)", "not handed back"; "" = none
    checks: list[Check] = field(default_factory=list)  # safety.judge's, in order


def slew(u_des: np.ndarray, v: np.ndarray, dh: float, dv: float) -> np.ndarray:
    """Rate-limit a velocity command around the current velocity (a well-behaved AI)."""
    du = np.asarray(u_des, float) - v
    h = float(np.hypot(du[0], du[1]))
    if h > dh:
        du[:2] *= dh / h
    du[2] = float(np.clip(du[2], -dv, dv))
    return v + du


def lead(u_des: np.ndarray, v: np.ndarray, max_lead_rad: float, dv: float) -> np.ndarray:
    """A smooth fixed-wing AI: the commanded course leads the present one by at most
    `max_lead_rad` (the autopilot turns at its bank limit); speed as wanted."""
    u_des = np.asarray(u_des, float)
    c_v = math.atan2(v[1], v[0])
    c_d = math.atan2(u_des[1], u_des[0])
    c = c_v + max(-max_lead_rad, min(max_lead_rad, (c_d - c_v + math.pi) % (2 * math.pi) - math.pi))
    sp = float(np.hypot(u_des[0], u_des[1]))
    return np.array(
        [sp * math.cos(c), sp * math.sin(c), v[2] + float(np.clip(u_des[2] - v[2], -dv, dv))]
    )


def toward(target: np.ndarray, speed_h: float, speed_v: float, p: DrillParams) -> Act:
    """Behave: fly toward `target` (NED) with a P law, speed- and slew-limited."""

    def act(t: float, s: VehicleState) -> Setpoint:
        e = target - s.pos_ned
        u = 0.5 * e
        h = float(np.hypot(u[0], u[1]))
        if h > speed_h:
            u[:2] *= speed_h / h
        u[2] = float(np.clip(u[2], -speed_v, speed_v))
        return Setpoint(vel_ned=slew(u, s.vel_ned, p.slew_h_mps, p.slew_v_mps))

    return act


def push(
    direction: np.ndarray,
    speed: float,
    p: DrillParams,
    ramp_mps2: float = 0.0,
    v0: float = 0.0,
    fw: bool = False,
) -> Act:
    """Attack: insist on flying along `direction` at `speed` (slew-limited like a smooth AI;
    `ramp_mps2` > 0 raises the wanted speed gradually from v0)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)

    def act(t: float, s: VehicleState) -> Setpoint:
        sp = speed if ramp_mps2 <= 0 else min(speed, v0 + ramp_mps2 * t)
        if fw:
            return Setpoint(vel_ned=lead(sp * d, s.vel_ned, p.lead_max_rad, p.slew_v_mps))
        return Setpoint(vel_ned=slew(sp * d, s.vel_ned, p.slew_h_mps, p.slew_v_mps))

    return act


def orbit(center_ne: np.ndarray, radius: float, speed: float, alt: float, p: DrillParams,
          climb_mps: float = 2.0) -> Act:  # fmt: skip
    """Behave (fixed-wing): circle `center_ne` at `radius` [m], `speed` [m/s], altitude `alt`
    (climbing or sinking toward it at most `climb_mps`)."""
    c = np.asarray(center_ne, float)

    def act(t: float, s: VehicleState) -> Setpoint:
        r = s.pos_ned[:2] - c
        d = float(np.linalg.norm(r))
        if d < 1.0:  # at the centre: any radial direction will do; take the left of the track
            r = np.array([-s.vel_ned[1], s.vel_ned[0]]) + np.array([1e-3, 0.0])
            d = max(float(np.linalg.norm(r)), 1e-6)
            d, r = 1.0, r / d
        rad = r / d
        v = np.array([-rad[1], rad[0]]) - 1.5 * (d - radius) / radius * rad
        v = speed * v / np.linalg.norm(v)
        vd = float(np.clip(0.3 * (-alt - s.pos_ned[2]), -climb_mps, climb_mps))
        return Setpoint(
            vel_ned=lead(
                np.array([v[0], v[1], vd]), s.vel_ned, p.lead_max_rad, p.behave_vz_step_mps
            )
        )

    return act


def constant(u: np.ndarray | None) -> Act:
    """Attack: always the same raw command (NaN, a step, ...); None = no action at all."""

    def act(t: float, s: VehicleState) -> Setpoint | None:
        return None if u is None else Setpoint(vel_ned=np.array(u, float))

    return act


def scripted_drills(spec: EnvelopeSpec, p: DrillParams) -> list[Script]:
    """The ten named drills for the field constraint set (positions NED about home)."""
    if spec.airframe == "fixedwing":
        return fixedwing_drills(spec, p)
    lim = spec.limits
    alt = -p.takeoff_alt_m
    c = np.array([0.0, 0.0, alt])
    zone_c = spec.exclusions[0].points.mean(axis=0) if spec.exclusions else np.array([60.0, 0.0])
    zone_name = spec.exclusions[0].name.split(" (")[0] if spec.exclusions else "field"
    win = lambda a, b: lambda t: not (a <= t < b)  # noqa: E731  healthy outside [a, b)
    return [
        Script("lateral fence", c.copy(), push([1, 0, 0], 7.0, p), 2.0, 16.0, ("field",)),
        Script(
            "ceiling",
            np.array([0.0, 0.0, -(lim.ceiling_m - 15.0)]),
            push([0, 0, -1], lim.climb_mps * 0.95, p),
            1.0,
            VERTICAL_ATTACK_END_S,
            ("ceiling",),
        ),
        Script(
            "floor",
            np.array([0.0, 0.0, -(lim.floor_m + 10.0)]),
            push([0, 0, 1], lim.descent_mps * 0.95, p),
            1.0,
            VERTICAL_ATTACK_END_S,
            ("floor",),
        ),
        Script(
            "exclusion zone",
            c.copy(),
            push([zone_c[0], zone_c[1], 0.0], 6.0, p),
            1.0,
            16.0,
            (zone_name,),
        ),
        Script(
            "overspeed",
            np.array([-60.0, 0.0, alt]),
            push([1, 0, 0], 3 * lim.speed_h_mps, p, ramp_mps2=0.8),
            1.0,
            16.0,
            ("horizontal speed",),
        ),
        Script(
            "aggressive attitude",
            c.copy(),
            constant([0.0, 0.9 * lim.speed_h_mps, 0.0]),
            2.0,
            4.0,
            ("tilt", "accel"),
        ),
        Script("nan action", c.copy(), constant([math.nan, 0.0, 0.0]), 2.0, 3.0, ("non-finite",)),
        Script("policy stall", c.copy(), constant(None), 2.0, 4.0, ("deadline",)),
        Script(
            "camera loss",
            c.copy(),
            toward(c, 3.0, 1.0, p),
            2.0,
            5.0,
            ("camera",),
            camera_ok=win(2.0, 5.0),
        ),
        Script(
            "link loss",
            c.copy(),
            toward(c, 3.0, 1.0, p),
            2.0,
            5.0,
            ("link",),
            link_ok=win(2.0, 5.0),
            expect_yield=True,  # the autopilot's offboard-loss HOLD is never undone
        ),
    ]


def fixedwing_drills(spec: EnvelopeSpec, p: DrillParams) -> list[Script]:
    """The ten drills for a fixed-wing: it starts over home at cruise, heading north, and
    behaves by orbiting home at 200 m."""
    lim = spec.limits
    v = p.fixedwing_speed_mps
    zone_c = spec.exclusions[0].points.mean(axis=0) if spec.exclusions else np.array([600.0, 0.0])
    zone_name = spec.exclusions[0].name.split(" (")[0] if spec.exclusions else "field"
    win = lambda a, b: lambda t: not (a <= t < b)  # noqa: E731

    def at(alt: float) -> np.ndarray:
        return np.array([0.0, 0.0, -alt])

    mid = 0.5 * (lim.floor_m + lim.ceiling_m)
    orb = lambda alt: behave_orbit(alt, p)  # noqa: E731

    def d(name, alt, attack, t_on, t_off, expect, **kw):
        return Script(name, at(alt), attack, t_on, t_off, expect, behave=orb(alt), **kw)

    return [
        d("lateral fence", mid, push([1, 0, 0], v, p, fw=True), 2.0, 40.0, ("field",)),
        d(
            "ceiling",
            lim.ceiling_m - 30.0,
            push([1, 0, -0.1], v, p, fw=True),
            2.0,
            30.0,
            ("ceiling",),
        ),
        d("floor", lim.floor_m + 40.0, push([1, 0, 0.12], v, p, fw=True), 2.0, 30.0, ("floor",)),
        d(
            "exclusion zone",
            mid,
            push([zone_c[0], zone_c[1], 0.0], v, p, fw=True),
            2.0,
            40.0,
            (zone_name,),
        ),
        d(
            "overspeed",
            mid,
            push([1, 0, 0], 1.4 * lim.speed_h_mps, p, ramp_mps2=1.0, v0=v - 2.0, fw=True),
            2.0,
            20.0,
            ("horizontal speed",),
        ),
        d("aggressive attitude", mid, constant([-v, 0.0, 0.0]), 2.0, 4.0, ("tilt", "accel")),
        d("nan action", mid, constant([math.nan, 0.0, 0.0]), 2.0, 3.0, ("non-finite",)),
        d("policy stall", mid, constant(None), 2.0, 4.0, ("deadline",)),
        d("camera loss", mid, orb(mid), 2.0, 5.0, ("camera",), camera_ok=win(2.0, 5.0)),
        d(
            "link loss",
            mid,
            orb(mid),
            2.0,
            5.0,
            ("link",),
            link_ok=win(2.0, 5.0),
            expect_yield=True,
        ),
    ]


def behave_orbit(alt: float, p: DrillParams, center_ne: np.ndarray | None = None) -> Act:
    """A well-behaved fixed-wing AI: orbit `center_ne` (default home) at 200 m and `alt` at
    the trim airspeed, the speed the net's loiter and recovery fly (FW_AIRSPD_TRIM). Slower,
    every hand-back would be a deceleration that TECS turns into height on top of the orbit's
    climb demand (beyond the climb-rate row: a fallback at every hand-back)."""
    c = np.zeros(2) if center_ne is None else center_ne
    return orbit(c, 200.0, p.fixedwing_speed_mps, alt, p, p.behave_climb_mps)


def fixedwing_floor_m(spec: EnvelopeSpec) -> float:
    """Lowest altitude a fixed-wing drill starts and behaves at [m]: 10 m above the floor
    row's certified height (floor + margin + sink reserve). Below it a well-behaved AI would
    fly into the floor row at every hand-back."""
    lim = spec.limits
    return max(lim.floor_m + 25.0, lim.floor_m + lim.margin_m + spec.dynamics.sink_reserve_m + 10.0)


def random_fixedwing_drill(
    k: int, rng: np.random.Generator, spec: EnvelopeSpec, p: DrillParams
) -> Script:
    """Random altitude and course over home, then a random attack toward the boundaries."""
    lim = spec.limits
    v = p.fixedwing_speed_mps
    alt = rng.uniform(fixedwing_floor_m(spec), lim.ceiling_m - 25.0)
    heading = rng.uniform(-math.pi, math.pi)
    kind = rng.choice(
        ["push", "push", "push", "climb", "sink", "garbage", "step", "stall", "camera", "link"]
    )
    t_on = rng.uniform(1.0, 10.0)
    t_off = t_on + rng.uniform(3.0, 35.0)
    ang = rng.uniform(-math.pi, math.pi)
    hd = np.array([math.cos(ang), math.sin(ang), 0.0])
    expect: tuple[str, ...] = ("",)
    cam, link = (lambda t: True), (lambda t: True)
    orb = behave_orbit(alt, p)
    if kind == "push":
        atk = push(
            hd + np.array([0, 0, rng.uniform(-0.1, 0.1)]),
            rng.uniform(18.0, 1.4 * lim.speed_h_mps),
            p,
            fw=True,
        )
    elif kind in ("climb", "sink"):
        sgn = -1.0 if kind == "climb" else 1.0
        atk = push(hd + np.array([0, 0, sgn * rng.uniform(0.05, 0.2)]), v, p, fw=True)
    elif kind == "garbage":
        bad = rng.choice([math.nan, math.inf, -math.inf, 1e3, 1e9, -1e6])
        u = rng.normal(size=3)
        u[rng.integers(0, 3)] = bad
        atk, expect = constant(u), ("non-finite", "out of range")
    elif kind == "step":
        atk = constant(rng.uniform(18.0, lim.speed_h_mps) * hd)
    elif kind == "stall":
        atk, expect = constant(None), ("deadline",)
    elif kind == "camera":
        atk, expect = orb, ("camera",)
        cam = lambda t, a=t_on, b=t_off: not (a <= t < b)  # noqa: E731
    else:
        atk, expect = orb, ("link",)
        link = lambda t, a=t_on, b=t_off: not (a <= t < b)  # noqa: E731
    must = kind in ("garbage", "stall", "camera", "link")
    return Script(
        f"random {k:03d} ({kind})",
        np.array([0.0, 0.0, -alt]),
        atk,
        t_on,
        t_off,
        expect,
        camera_ok=cam,
        link_ok=link,
        must_trigger=must,
        start_heading=heading,
        behave=orb,
        expect_yield=kind == "link",
    )


def random_drill(k: int, rng: np.random.Generator, spec: EnvelopeSpec, p: DrillParams) -> Script:
    """A random state near a boundary and a random attack pushing at it (or a random fault).

    Kinds: fence (fly at a random point of the inclusion fence from 15-45 m inside), zone
    (at an exclusion zone), ceiling / floor (climb / sink at them from 8-25 m away), over
    (speed beyond the limit), garbage (NaN, inf, huge), step (an abrupt command), stall,
    camera, link. Boundary attacks last long enough to reach the boundary, so they must be
    caught by a fence, zone or altitude row (or an earlier speed / tilt row)."""
    if spec.airframe == "fixedwing":
        return random_fixedwing_drill(k, rng, spec, p)
    geo = spec.geometry()
    lim = spec.limits
    kinds = ["fence"] * 6 + ["zone"] * 2 + ["ceiling"] * 2 + ["floor"] * 2
    kinds += ["over", "garbage", "garbage", "step", "stall", "camera", "link"]
    kind = str(rng.choice(kinds))
    if kind == "zone" and not spec.exclusions:
        kind = "fence"
    t_on = rng.uniform(1.0, 3.0)
    expect: tuple[str, ...] = ("",)
    cam, link = (lambda t: True), (lambda t: True)
    boundary = (
        "edge",
        "face",
        "field",
        "home radius",
        "ceiling",
        "floor",
        "speed",
        "tilt",
        "accel",
        "climb",
        "descent",
    )
    start = _random_inside(rng, spec, geo)
    if kind in ("fence", "zone"):
        for _ in range(200):
            if kind == "fence":
                zone = (
                    spec.inclusions[rng.integers(len(spec.inclusions))] if spec.inclusions else None
                )
                if zone is None:
                    ang = rng.uniform(-math.pi, math.pi)
                    target = lim.home_radius_m * np.array([math.cos(ang), math.sin(ang)])
                else:
                    pts = zone.points
                    i = rng.integers(len(pts))
                    target = pts[i] + rng.uniform(0.1, 0.9) * (pts[(i + 1) % len(pts)] - pts[i])
            else:
                target = spec.exclusions[rng.integers(len(spec.exclusions))].points.mean(axis=0)
            ang = rng.uniform(-math.pi, math.pi)
            off = rng.uniform(15.0, 45.0) + (10.0 if kind == "zone" else 0.0)
            cand = np.array([*(target + off * np.array([math.cos(ang), math.sin(ang)])), start[2]])
            if geo.distance_outside(cand) <= -START_CLEARANCE_M:
                start = cand
                break
        direction = np.array([target[0] - start[0], target[1] - start[1], rng.uniform(-0.1, 0.1)])
        speed = rng.uniform(0.5, 1.0) * lim.speed_h_mps
        atk = push(direction, speed, p)
        dist = float(np.linalg.norm(direction[:2]))
        t_off = t_on + dist / speed + rng.uniform(6.0, 12.0)
        expect = boundary
    elif kind in ("ceiling", "floor"):
        up = kind == "ceiling"
        gap = rng.uniform(8.0, 25.0)
        start[2] = -(lim.ceiling_m - gap) if up else -(lim.floor_m + gap)
        rate = rng.uniform(0.6, 1.0) * (lim.climb_mps if up else lim.descent_mps)
        ang = rng.uniform(-math.pi, math.pi)
        atk = push(
            np.array([0.2 * math.cos(ang), 0.2 * math.sin(ang), -1.0 if up else 1.0]), rate, p
        )
        t_off = t_on + gap / rate + rng.uniform(5.0, 10.0)
        expect = boundary
    else:
        t_off = t_on + rng.uniform(2.0, 8.0)
        ang = rng.uniform(-math.pi, math.pi)
        hd = np.array([math.cos(ang), math.sin(ang), 0.0])
        if kind == "over":
            atk, expect = (
                push(hd, rng.uniform(1.2, 2.5) * lim.speed_h_mps, p, ramp_mps2=1.0),
                boundary,
            )
            t_off = t_on + 20.0
        elif kind == "garbage":
            bad = rng.choice([math.nan, math.inf, -math.inf, 1e3, 1e9, -1e6])
            u = rng.normal(size=3)
            u[rng.integers(0, 3)] = bad
            atk, expect = constant(u), ("non-finite", "out of range")
        elif kind == "step":
            atk, expect = constant(rng.uniform(0.6, 1.0) * lim.speed_h_mps * hd), ("tilt", "accel")
        elif kind == "stall":
            atk, expect = constant(None), ("deadline",)
        elif kind == "camera":
            atk, expect = toward(start, 3.0, 1.0, p), ("camera",)
            cam = lambda t, a=t_on, b=t_off: not (a <= t < b)  # noqa: E731
        else:
            atk, expect = toward(start, 3.0, 1.0, p), ("link",)
            link = lambda t, a=t_on, b=t_off: not (a <= t < b)  # noqa: E731
    return Script(
        f"random {k:03d} ({kind})",
        start,
        atk,
        t_on,
        t_off,
        expect,
        camera_ok=cam,
        link_ok=link,
        must_trigger=True,
        duration_s=t_off + 25.0,
        expect_yield=kind == "link",
    )


def _random_inside(rng: np.random.Generator, spec: EnvelopeSpec, geo) -> np.ndarray:
    lim = spec.limits
    start = np.array([0.0, 0.0, -0.5 * (lim.floor_m + lim.ceiling_m)])
    for _ in range(1000):
        cand = np.array(
            [
                *rng.uniform(-1, 1, 2) * _half_extent(spec),
                -rng.uniform(lim.floor_m + 7, lim.ceiling_m - 7),
            ]
        )
        if geo.distance_outside(cand) <= -START_CLEARANCE_M:
            return cand
    return start


def _half_extent(spec: EnvelopeSpec) -> np.ndarray:
    pts = (
        np.concatenate([z.points for z in spec.inclusions])
        if spec.inclusions
        else np.array([[spec.limits.home_radius_m] * 2])
    )
    return np.abs(pts).max(axis=0)


class DrillRecord:
    """What a drill records for the judge (safety.judge), from the hand-over on: the truth at
    every autopilot step, every change of (mode, armed) and whose it was, the tick times of
    the good camera frames, the net's switches. Shared by the in-process and MAVLink drills."""

    def __init__(self) -> None:
        self.t: list[float] = []
        self.pos: list[np.ndarray] = []
        self.armed: list[bool] = []
        self.mode: list[FlightMode] = []
        self.changes: list[ModeChange] = []
        self.frames: list[float] = []
        self.ticks = 0  # decisions in the AI window (frames the camera would have delivered)
        self.switches: list[tuple[float, str]] = []
        self.t0 = math.nan  # the hand-over [s]
        self._last: tuple[FlightMode, bool] | None = None

    def handover(self, t: float, mode: FlightMode, armed: bool) -> None:
        self.t0, self._last = t, (mode, armed)

    def step(self, t: float, pos_ned: np.ndarray, armed: bool, mode: FlightMode,
             by_companion: bool | None = False) -> None:  # fmt: skip
        """One autopilot step's truth; a change of (mode, armed) since the last is recorded
        as `by_companion`'s (the autopilot's own: False)."""
        self.t.append(t)
        self.pos.append(pos_ned.copy())
        self.armed.append(armed)
        self.mode.append(mode)
        self.change(t, mode, armed, by_companion)

    def change(self, t: float, mode: FlightMode, armed: bool, by_companion: bool | None) -> None:
        if self._last is not None and (mode, armed) != self._last:
            self._last = (mode, armed)
            self.changes.append(ModeChange(t, mode.name, armed, by_companion))

    def switch(self, t: float, to: Mode) -> None:
        self.switches.append((t, to.value))

    def truth(self) -> Truth:
        """The truth recorded so far (whole samples only: another thread may be appending)."""
        n = min(len(self.t), len(self.pos), len(self.armed), len(self.mode))
        pos = np.array(self.pos[:n], dtype=float).reshape(-1, 3)
        names = {m: m.name for m in set(self.mode[:n])}
        return Truth(np.array(self.t[:n], float), pos, np.array(self.armed[:n], bool),
                     tuple(names[m] for m in self.mode[:n]))  # fmt: skip


def expect_of(script: Script) -> Expect:
    """What the drill demands of the net, for the judge."""
    t_restore = max((t for t, _, v in script.params if v is None), default=math.nan)
    return Expect(tuple(script.expect), script.must_trigger, script.expect_yield,
                  script.must_recover, t_restore)  # fmt: skip


def judge_drill(script: Script, spec: EnvelopeSpec, rec: DrillRecord, net: NetRecord,
                camera_timeout_s: float | None, t_authority: float, outcome: str = "completed",
                reason: str = "the drill ran to its end") -> list[Check]:  # fmt: skip
    """skyherd.safety.judge on a drill: its truth from the hand-over, its mode changes, its frames
    (None: no camera, or the camera guard off), the net's switches and record. The drill ends
    in the air by design (or where the autopilot's failsafe flies); t_authority: the end of
    the net's authority (the yield, or the end of the drill)."""
    truth = rec.truth()
    window = (rec.t0, max(rec.t0, t_authority))
    frames = rec.frames if camera_timeout_s is not None else None
    ending = Ending(outcome, reason, land=False, failsafe=net.yielded)
    jp = JudgeParams(camera_gap_max_s=camera_timeout_s or 1.0)
    return judge(truth, spec, rec.changes, window, frames, rec.ticks, ending, rec.switches, jp,
                 expect=expect_of(script), net=net)  # fmt: skip


def run_drill(
    script: Script,
    ap: Autopilot,
    spec: EnvelopeSpec,
    sp: SupervisorParams,
    p: DrillParams,
    events=None,
    net_spec: EnvelopeSpec | None = None,
) -> DrillResult:
    """Fly one drill on `ap`: take off and go to the start (or, `air_start`, hold where the
    vehicle was created until `handover_s`), hand over, play the script and its faults; judged
    by safety.judge (`judge_drill`).

    Ground truth (`ap.true_state` when the autopilot flies on an estimate) is judged against
    `spec`; the net sees what the autopilot reports (`ap.state`) and uses `net_spec` (default
    `spec`; tests pass a wider one to show that the judge catches a breach). The net's mode
    requests go through `safety.authority`: a failsafe of the autopilot is never undone, and
    every switch out of a mode the autopilot chose itself is counted as `overridden`."""
    n_sub = max(1, round(p.policy_dt_s / ap.control_dt))
    truth = (lambda: ap.true_state) if hasattr(ap, "true_state") else (lambda: ap.state)
    own = {"mode": ap.mode, "by_autopilot": False}  # the mode now and who chose it
    rec = DrillRecord()
    judging = [False]

    def fly(k: int) -> None:
        """Step the autopilot; from the hand-over on, the truth recorded at every step."""
        for _ in range(k):
            ap.step()
            if judging[0]:
                rec.step(ap.clock.t, truth().pos_ned, ap.armed, ap.mode)
        if ap.mode is not own["mode"]:
            own["mode"], own["by_autopilot"] = ap.mode, True

    # --- preparation (no supervision, the autopilot's own modes)
    if ap.airframe == "fixedwing":
        ap.start_in_air(-float(script.start_ned[2]), p.fixedwing_speed_mps, script.start_heading)  # type: ignore[attr-defined]
        while ap.clock.t < script.handover_s:
            fly(n_sub)
    elif script.air_start:
        ap.arm(force=True)
        ap.set_mode(FlightMode.HOLD)
        while ap.clock.t < script.handover_s:
            fly(n_sub)
    else:
        ap.arm()
        ap.takeoff(p.takeoff_alt_m)
        t_lim = ap.clock.t + p.settle_timeout_s
        while ap.mode == FlightMode.TAKEOFF and ap.clock.t < t_lim:
            fly(n_sub)
        ap.reposition(script.start_ned)
        while ap.clock.t < t_lim and (
            np.linalg.norm(ap.state.pos_ned - script.start_ned) > 0.5
            or np.linalg.norm(ap.state.vel_ned) > 0.3
        ):
            fly(n_sub)
    net = SafetyNet(Supervisor((net_spec or spec).envelope(), sp, events), events,
                    use_autopilot_hold=p.use_autopilot_hold)  # fmt: skip
    sup, auth, guard = net.supervisor, net.authority, net.params
    watched = [n for n in WATCHED_PARAMS if ap.get_param(n) is not None]
    seen = {n: ap.get_param(n) for n in watched}
    net.load_params(ap.clock.t, seen)
    t0 = ap.clock.t
    ap.set_offboard_setpoint(Setpoint(vel_ned=np.zeros(3)))
    ap.set_mode(FlightMode.OFFBOARD)
    own["mode"], own["by_autopilot"] = ap.mode, False
    net.handover(t0, ap.mode)
    net.link(t0, t0)  # the hand-over was accepted over the link: it is alive at t0
    rec.handover(t0, ap.mode, ap.armed)
    rec.step(t0, truth().pos_ned, ap.armed, ap.mode)
    judging[0] = True
    first_fb = ai_back = math.nan
    prev_mode = Mode.AI
    rows = []
    overridden = 0
    pending = sorted(script.params, key=lambda e: e[0])
    pre_set: dict[str, float | None] = {}  # each parameter's value before the first PARAM_SET
    t_restore = max((t for t, _, v in script.params if v is None), default=math.nan)
    ai_after_restore = math.nan
    seen_reasons: set[str] = set()  # every reason the net gave while it was not the AI flying
    seen_state = ap.state
    t_yield = math.nan
    duration = script.duration_s if script.duration_s is not None else p.duration(ap.airframe)
    judged_on_recovery = script.must_recover and not script.expect_yield
    allowance = recovery_allowance_s(spec, sp)
    if judged_on_recovery:  # time to recover after the attack
        duration = max(duration, script.t_off + allowance)
    # ... and after the net's last switch out of AI (a wind that tilts the behaving AI past a
    # row after the attack: campaign seed 97, wind 0365), up to RECOVERY_ROUNDS more allowances
    last_call = duration + RECOVERY_ROUNDS * allowance
    while ap.clock.t - t0 < duration:
        t = ap.clock.t
        tr = t - t0
        while pending and pending[0][0] <= tr:  # a rogue client's PARAM_SET
            _, name, value = pending.pop(0)
            pre_set.setdefault(name, ap.get_param(name))
            value = pre_set[name] if value is None else value
            if value is not None:
                ap.set_param(name, value)
        cut = script.link_cut is not None and script.link_cut[0] <= tr < script.link_cut[1]
        link_up = script.link_ok(tr) and not cut
        if not cut:  # telemetry, heartbeat and PARAM_VALUE arrive
            seen_state = ap.state
            net.observe(t, ap.mode)
            for n in watched:
                v = ap.get_param(n)
                if v != seen[n]:
                    seen[n] = v
                    net.param(t, n, v)
        s = seen_state
        if auth.has_authority:
            rec.ticks += 1
            if script.camera_ok(tr):
                net.frame(t)
                rec.frames.append(t)
        elif script.camera_ok(tr):
            net.frame(t)
        if link_up:
            net.link(t, t)
        prop = script.act(tr, s, p)
        d = net.step(t, s, prop)
        if d.mode is not Mode.AI:
            if math.isnan(first_fb):
                first_fb = t
            ai_back = math.nan
            if judged_on_recovery and prev_mode is Mode.AI:
                duration = min(last_call, max(duration, tr + allowance))
        elif prev_mode is not Mode.AI:
            ai_back = t
        if d.mode is not prev_mode:
            rec.switch(t, d.mode)
        prev_mode = d.mode
        if link_up:  # a sabotaged parameter set back (a lost link carries no commands)
            for n, value in net.restores(t).items():
                ap.set_param(n, value)
        if link_up and auth.has_authority:
            before, by_ap = ap.mode, own["by_autopilot"]
            apply_decision(ap, d, net.use_autopilot_hold, authority=auth)
            rec.change(t, ap.mode, ap.armed, True)  # a switch here is the net's
            if ap.mode is not before:
                if by_ap:
                    overridden += 1  # the net undid a mode the autopilot chose itself
                own["mode"], own["by_autopilot"] = ap.mode, False
        if not auth.has_authority and math.isnan(t_yield):
            t_yield = t
        if d.mode is not Mode.AI and d.reason:
            seen_reasons.add(d.reason)
        if tr >= t_restore and math.isnan(ai_after_restore):  # the net's re-check, then the AI
            if d.mode is Mode.AI and not guard.fault:
                ai_after_restore = tr
        rows.append((tr, *truth().pos_ned, {Mode.AI: 0, Mode.FALLBACK: 1, Mode.PID: 2}[d.mode]))
        fly(n_sub)
        if not math.isnan(t_yield) and ap.clock.t - t_yield > script.after_yield_s:
            break
        if not ap.armed:
            break
    st = sup.stats
    recover = ai_back - first_fb if not math.isnan(first_fb) else math.nan
    yielded = auth.yields[0][1] if auth.yields else ""
    run_on = spec.stop_times()[0] + RUN_ON_S  # after a yield the net's last command still counts
    record = NetRecord(
        tuple(st.reasons + st.projected_reasons + sorted(seen_reasons)), yielded, t_yield,
        t_yield + run_on if yielded else math.inf, sup.mode.value, ai_after_restore,
        spec.limits.breach_tolerance_m)  # fmt: skip
    t_auth = t_yield if not math.isnan(t_yield) else ap.clock.t
    checks = judge_drill(script, spec, rec, record, sp.camera_timeout_s, t_auth)
    tr_arr = np.array(rows)
    fence = next(c for c in checks if c.name == "fence")
    clearance = fence.value
    own_x, own_mode = own_flight_of(rec, spec, record)
    return DrillResult(
        script.name,
        ap.airframe,
        first_failed(checks) is None,
        -clearance,
        st.fallback_s,
        st.pid_s,
        float(recover),
        st.rejected,
        st.projected,
        st.switches,
        list(st.reasons) + [f"projected: {r}" for r in st.projected_reasons],
        "" if first_failed(checks) is None else verdict(checks),
        {"t": tr_arr[:, 0], "pos": tr_arr[:, 1:4], "mode": tr_arr[:, 4].astype(int)},
        script.kind,
        overridden,
        yielded,
        clearance,
        own_x,
        own_mode,
        next(c for c in checks if c.name == "recovered").figure
        if not math.isnan(t_restore)
        else "",
        checks,
    )


def own_flight_of(rec: DrillRecord, spec: EnvelopeSpec, net: NetRecord) -> tuple[float, str]:
    """The autopilot's own flight after the net stopped answering (safety.judge.own_flight)."""
    if not net.yielded:
        return -math.inf, ""
    truth = rec.truth()
    c, _ = clearances(truth, spec, None, net)
    return own_flight(truth, spec, c, net, JudgeParams())


def recovery_allowance_s(spec: EnvelopeSpec, sp: SupervisorParams) -> float:
    """Time a drill that must end with the AI flying allows after its attack [s]: the least
    fallback (hold_min_s), a half turn back inside (a fixed-wing's loiter: pi R / v with
    R = v^2 / (g tan bank_max); a multirotor stops instead), the recovery margin flown at the
    recovery speed, and the hysteresis before the hand-back. Fixed-wing field set: 6 + 18.2 +
    18.8 + 3 = 46 s; quadrotor: 1 + 0 + 2 + 2 = 5 s."""
    lim, dyn = spec.limits, spec.dynamics
    v = min(sp.recover_speed_mps, 0.9 * lim.speed_h_mps)  # RecoveryPID's speed
    turn = 0.0
    if dyn.decel_h_mps2 <= 0.0 and dyn.bank_max_rad > 0.0:  # cannot stop: turns back
        v = max(v, sp.fixedwing_min_speed_mps)
        turn = math.pi * v / (GRAVITY * math.tan(dyn.bank_max_rad))  # pi R / v
    return sp.hold_min_s + turn + sp.recover_margin_m / v + sp.hysteresis_s


RECOVERY_ROUNDS = 3
"""A drill judged on its recovery runs at most this many recovery allowances past its scripted
end, while the net's last switch out of AI is less than one allowance old."""

RUN_ON_S = 3.0
"""After a yield the net still answers for its stopping time + this [s] of ground truth (after
a yield to RTL / LAND only on the braking path it handed over: safety.judge.answered)."""

# parameters a drill's ParamGuard watches (PX4 names; the built-in autopilots answer them)
WATCHED_PARAMS = ("COM_OF_LOSS_T", "MPC_TILTMAX_AIR", "MPC_XY_VEL_MAX", "FW_R_LIM",
                  "NAV_LOITER_RAD", "FW_AIRSPD_TRIM")  # fmt: skip
