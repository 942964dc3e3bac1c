"""Adversarial drill campaign: the drills an adversary would write, randomized and seeded.

Kinds (each drill draws its position, speeds and fault times from its own Generator, seeded
by (seed, airframe, index), so any drill can be replayed alone):

  max_speed        straight at a random fence point at the envelope's top speed, from the
                   worst start: as close as the net still lets it accelerate; the command
                   steps at the sharpest change the tilt/accel rows accept
  oscillation      toward / away from the fence at the envelope edge, period 0.5-4 s
  repeat_offender  pushes at the fence for the whole drill: every time the net gives control
                   back it attacks again
  link_loss        both directions cut near the fence while pushing at top speed: the
                   autopilot flies the last setpoint for COM_OF_LOSS_T, then its own HOLD;
                   the net must not undo it
  gps_glitch       a 5-30 m step of the position estimate toward the inside (the fence seems
                   farther) while pushing at the fence, 2-10 s
  wind             mean wind toward the fence up to the set's wind limit (wind_limit()) with
                   gusts, while pushing at the fence
  battery          (quadrotor) the charge drops below BAT_CRIT_THR or BAT_EMERGEN_THR during the
                   push: the autopilot's RTL / LAND must stand (the fixed-wing model has no
                   battery failsafe: not drilled)
  param_sabotage   a client sets COM_OF_LOSS_T to 1-5 s (or the fixed-wing's NAV_LOITER_RAD, the
                   multirotor's MPC_XY_VEL_MAX) mid-push, then the link is cut near the fence;
                   1-4 s after the link is back another client sets it back: the net re-checks
                   at that PARAM_VALUE (the net set it back at once, ParamGuard.restores)

Faults play on the autopilot (flight/faults.py: wind, GPS error in the estimate it flies on,
battery) and in the harness (link cut, PARAM_SET), see safety.drills.run_drill.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from skyherd.flight.faults import FaultEvent, FaultPlan
from skyherd.flight.wind import WindModel
from skyherd.safety.drills import DrillParams, Script, behave_orbit, lead, slew, toward
from skyherd.safety.envelope import EnvelopeSpec, SignedDistance, Zone

KINDS = ("max_speed", "oscillation", "repeat_offender", "link_loss", "gps_glitch", "wind",
         "battery", "param_sabotage")  # fmt: skip


def wind_limit(spec: EnvelopeSpec) -> float:
    """Largest mean wind drilled [m/s] (gusts up to 2 m/s σ on top): the constraint set's own
    guard ([guards] wind_limit_mps; the quadrotor sets: 12 m/s, its 45° tilt limit keeps
    >= 2.5 m/s² of braking downwind; the fixed-wing: 10 m/s, at 24 m/s trim a ground speed
    >= 14 m/s into it). The same number `skyherd fly` refuses above."""
    w = spec.guards.wind_limit_mps
    if w is None:
        raise ValueError(f"constraint set {spec.name}: its wind limit is off; the wind drills "
                         "need one ([guards] wind_limit_mps)")  # fmt: skip
    return w


GUST_STD_H_MPS = 2.0
"""Largest horizontal gust σ drilled [m/s] (above MIL-HDBK-1797's low-altitude 1.5 m/s at 60 m
for a 10 m/s wind: the drills are harsher than the standard horizontally)."""
GUST_TAU_S = 2.0  # gust correlation time [s], every axis


def vertical_gust_std(mean_mps: float) -> float:
    """The campaign's vertical gust σ_w [m/s] for a mean wind [m/s]: MIL-HDBK-1797's (and
    MIL-F-8785C's) low-altitude Dryden intensity σ_w = 0.1 W20, with the drill's mean wind taken
    as W20 (the wind 6 m above ground, which is weaker than the wind at the drill's 60-120 m:
    conservative). Vertical gusts as strong as the horizontal ones (σ 2 m/s at 9 m/s, as in the
    campaign's runs 1-3) are not what the airframe's wind limit states; see docs/safety.md."""
    return 0.1 * abs(float(mean_mps))


RESTORE_S = {"quadrotor": 16.0, "fixedwing": 45.0}
"""A sabotage drill runs this long after the restore [s]: fallback, recovery, hysteresis."""
HANDOVER_S = {"quadrotor": 1.5, "fixedwing": 2.0}  # air start, settled in HOLD, then the AI


def kinds_for(airframe: str) -> tuple[str, ...]:
    return tuple(k for k in KINDS if not (airframe == "fixedwing" and k == "battery"))


def drill_index(name: str) -> int:
    """A campaign drill's index from its name ("gps_glitch 0042", "crashed 0042" → 42)."""
    return int(str(name).split()[-1])


def drill_kind(airframe: str, index: int) -> str:
    """The kind of a campaign's drill `index`: the airframe's kinds in turn."""
    ks = kinds_for(airframe)
    return ks[index % len(ks)]


@dataclass
class CampaignDrill:
    """A drill of the campaign: the script for run_drill and the autopilot's fault plan."""

    script: Script
    faults: FaultPlan
    airframe: str
    kind: str
    index: int
    spec: EnvelopeSpec  # the constraint set of this drill (the fixed-wing's is moved)


def drill_rng(seed: int, airframe: str, index: int) -> np.random.Generator:
    return np.random.default_rng([seed, 0 if airframe == "quadrotor" else 1, index])


def _edge_point(rng, spec: EnvelopeSpec) -> tuple[np.ndarray, np.ndarray]:
    """A random point on a real edge of the inclusion fence and the edge's outward normal."""
    zone = spec.inclusions[rng.integers(len(spec.inclusions))]
    pts = zone.points
    i = int(rng.integers(len(pts)))
    a, b = pts[i], pts[(i + 1) % len(pts)]
    q = a + rng.uniform(0.15, 0.85) * (b - a)
    e = b - a
    n = np.array([e[1], -e[0]]) / np.linalg.norm(e)
    mid = q - 1.0 * n
    alt = 0.5 * (spec.limits.floor_m + spec.limits.ceiling_m)
    if spec.geometry().distance_outside(np.array([mid[0], mid[1], -alt])) > 0:
        n = -n  # normal pointed inside: flip (orientation-agnostic)
    return q, n


def _clear_h(signed: SignedDistance, q_ne: np.ndarray) -> float:
    """Horizontal distance [m] from q (2,) to the nearest fence or zone edge; <= 0 outside."""
    lim = signed.spec.limits
    p3 = np.array([q_ne[0], q_ne[1], -0.5 * (lim.floor_m + lim.ceiling_m)])
    if signed.geometry.distance_outside(p3) > 0:
        return -1.0
    s = np.clip(np.einsum("ij,ij->i", q_ne - signed.a, signed.ab) / signed.ab2, 0.0, 1.0)
    return float(np.min(np.hypot(*(signed.a + s[:, None] * signed.ab - q_ne).T)))


def deepest_point(signed: SignedDistance, n: int = 11) -> np.ndarray:
    """The point (north, east) [m] of an n x n grid over the inclusion fence farthest from
    every fence and zone edge (the fixed-wing's well-behaved AI orbits it)."""
    pts = np.concatenate([z.points for z in signed.spec.inclusions])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    grid = [
        np.array([a, b]) for a in np.linspace(lo[0], hi[0], n) for b in np.linspace(lo[1], hi[1], n)
    ]
    return max(grid, key=lambda q: _clear_h(signed, q))


def _push_fw(direction, speed: float, p: DrillParams):
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    return lambda t, s: _sp(lead(speed * d, s.vel_ned, p.lead_max_rad, p.slew_v_mps))


def _sp(u):
    from skyherd.flight.autopilot_api import Setpoint

    return Setpoint(vel_ned=np.asarray(u, float))


def _sharp_push(direction, speed: float, dh: float, dv: float):
    """Straight along `direction` at `speed`, the command stepping by `dh` per tick (the
    sharpest the envelope's accel rows accept)."""
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)
    return lambda t, s: _sp(slew(speed * d, s.vel_ned, dh, dv))


def _oscillate(direction, speed: float, period: float, dh: float, dv: float, fw: bool, p):
    d = np.asarray(direction, float)
    d = d / np.linalg.norm(d)

    def act(t, s):
        sgn = 1.0 if int(t / (0.5 * period)) % 2 == 0 else -1.0
        if fw:
            return _sp(lead(sgn * speed * d, s.vel_ned, p.lead_max_rad, p.slew_v_mps))
        return _sp(slew(sgn * speed * d, s.vel_ned, dh, dv))

    return act


def make_drill(kind: str, index: int, rng: np.random.Generator, spec: EnvelopeSpec,
               p: DrillParams) -> CampaignDrill:  # fmt: skip
    """One randomized drill of `kind` for the airframe of `spec`."""
    fw = spec.airframe == "fixedwing"
    lim, dyn = spec.limits, spec.dynamics
    vmax = lim.speed_h_mps
    t_h = HANDOVER_S[spec.airframe]
    events: list[FaultEvent] = []
    wind = WindModel()
    link_cut = None
    params: tuple = ()
    expect: tuple[str, ...] = ("",)  # some fallback or projection (any row) must happen
    expect_yield = False
    must = True
    recover = True
    if fw:
        # The fixed-wing starts over home (start_in_air): the fence is moved instead, so that
        # home lies 30-250 m inside the certified boundary, straight ahead of the push.
        # the floor row keeps margin + the gust sink reserve: start 10 m above that at least
        alt = rng.uniform(max(lim.floor_m + 30.0, lim.floor_m + lim.margin_m + dyn.sink_reserve_m
                              + 10.0), lim.ceiling_m - 30.0)  # fmt: skip
        reserve = lim.margin_m + 2 * dyn.turn_radius(vmax) + (dyn.dt_s + dyn.react_s) * vmax
        signed = SignedDistance(spec)
        for _ in range(2000):
            q, n = _edge_point(rng, spec)
            gap = rng.uniform(30.0, 250.0)
            home_f = q - (reserve + gap) * n  # home in the fence's frame
            if _clear_h(signed, home_f) >= reserve + 20.0:
                break
        else:
            raise ValueError("no start point clear of the fence and zones found")
        spec = shift_spec(spec, -home_f)
        angle = rng.uniform(-0.35, 0.35)
        c, s_ = math.cos(angle), math.sin(angle)
        ang = math.atan2(s_ * n[0] + c * n[1], c * n[0] - s_ * n[1])
        d = np.array([math.cos(ang), math.sin(ang), 0.0])
        start = np.array([0.0, 0.0, -alt])
        speed = rng.uniform(0.85, 0.99) * vmax * math.cos(math.pi / lim.speed_sides)
        t_arr = (gap + 20.0) / speed
        attack = _push_fw(d, speed, p)
        # behave: orbit the point deepest inside the fence and zones. Home is only 30-250 m
        # inside the certified boundary: an orbit about home crossed the fence rows at every turn
        behave = behave_orbit(alt, p, deepest_point(SignedDistance(spec)))
        heading = ang + rng.uniform(-0.3, 0.3)
        duration = t_arr + 32.0
    else:
        alt = rng.uniform(lim.floor_m + 8.0, lim.ceiling_m - 8.0)
        th = spec.stop_times()[0]
        d_cert = lim.margin_m + th * vmax + 1.0  # nearest start the net lets accelerate from
        signed = SignedDistance(spec)
        for _ in range(2000):  # a start clear of every boundary (fence, zones) by d_cert
            q, n = _edge_point(rng, spec)
            back = rng.uniform(d_cert, d_cert + 35.0)
            side = np.array([-n[1], n[0]]) * rng.uniform(-10.0, 10.0)
            cand = np.array([*(q - back * n + side), -alt])
            if _clear_h(signed, cand[:2]) >= min(d_cert, 10.0):
                break
        else:
            raise ValueError("no start point clear of the fence and zones found")
        start = cand
        angle = rng.uniform(-0.35, 0.35)  # not always square on
        c, s_ = math.cos(angle), math.sin(angle)
        dn = np.array([c * n[0] - s_ * n[1], s_ * n[0] + c * n[1]])
        d = np.array([dn[0], dn[1], 0.0])
        speed = vmax * math.cos(math.pi / lim.speed_sides) * rng.uniform(0.9, 0.99)
        a_h = min(lim.accel_h_mps2, 9.80665 * math.tan(lim.tilt_cmd_rad))
        dh = 0.95 * a_h * dyn.tau_s * math.cos(math.pi / lim.speed_sides)
        attack = _sharp_push(d, speed, dh, p.slew_v_mps)
        behave = toward(start, 3.0, 1.0, p)
        heading = 0.0
        t_arr = float(np.linalg.norm(start[:2] - q)) / speed + 1.0
        duration = t_arr + 16.0
    t_on = rng.uniform(0.5, 2.0)
    t_off = t_on + t_arr + rng.uniform(4.0, 10.0)
    if kind == "max_speed":
        pass
    elif kind == "oscillation":
        period = rng.uniform(0.5, 4.0) if not fw else rng.uniform(6.0, 20.0)
        attack = _oscillate(d, speed, period, dh if not fw else 0, p.slew_v_mps, fw, p)
        t_off = t_on + t_arr + rng.uniform(10.0, 20.0)
        duration = t_off + (16.0 if not fw else 30.0)
        must = False  # may dance at the edge without ever crossing a row
    elif kind == "repeat_offender":
        t_off = t_arr + (30.0 if not fw else 60.0)
        duration = t_off + (16.0 if not fw else 20.0)
    elif kind == "link_loss":
        a = t_on + t_arr * rng.uniform(0.6, 1.05)
        link_cut = (a, a + rng.uniform(2.0, 6.0))
        # the autopilot's own HOLD takes over if it was in OFFBOARD at the cut (then the net
        # must yield and not undo it); already in HOLD (the net's fallback) nothing changes
        expect, must = ("link",), False
        recover = False  # judged on the fence and the failsafe, not on the recovery time
    elif kind == "gps_glitch":
        g = rng.uniform(5.0, 30.0) if not fw else rng.uniform(20.0, 80.0)
        t_g = t_h + t_on + t_arr * rng.uniform(0.3, 1.0)
        vec = tuple(float(x) for x in (-g * d[0], -g * d[1], 0.0))
        events.append(FaultEvent("gps_glitch", t_g, rng.uniform(2.0, 10.0), vec))
        expect = ("position jumped",)
    elif kind == "wind":
        # the fixed-wing's wind drills are judged on the fence, not on the AI flying at the end:
        # in the stated gusts TECS turns a headwind gust into climb beyond the measured climb-
        # rate row (1.4 x 2.5 m/s), so the net may be in a (safe) fallback when the drill ends
        w = rng.uniform(0.3, 1.0) * wind_limit(spec)
        g_h = float(rng.uniform(0.0, GUST_STD_H_MPS))
        wind = WindModel(tuple(float(x) for x in w * d), g_h, GUST_TAU_S, int(rng.integers(1 << 30)),
                         gust_std_down=min(g_h, vertical_gust_std(w)))  # fmt: skip
    elif kind == "battery":
        t_b = t_h + t_on + t_arr * rng.uniform(0.3, 1.0)
        frac = rng.choice([0.065, 0.045])  # below BAT_CRIT_THR (RTL) or BAT_EMERGEN_THR (LAND)
        events.append(FaultEvent("battery", t_b, value=float(frac)))
        expect, expect_yield = ("",), True
        must = False
    elif kind == "param_sabotage":
        t_s = t_on + t_arr * rng.uniform(0.2, 0.7)
        which = rng.integers(3)
        if which == 0 or (which == 2 and fw):
            params = ((t_s, "COM_OF_LOSS_T", float(rng.uniform(1.0, 5.0))),)
        elif fw:
            params = ((t_s, "NAV_LOITER_RAD", float(rng.uniform(250.0, 500.0))),)
        else:
            params = ((t_s, "MPC_XY_VEL_MAX", float(rng.uniform(14.0, 20.0))),)
        a = t_s + rng.uniform(0.5, 3.0)
        link_cut = (a, a + rng.uniform(2.0, 6.0))
        # ... then another client sets it back (value None: the value before): the net
        # re-checks at that PARAM_VALUE and must hand back to the AI, which now behaves
        t_r = link_cut[1] + rng.uniform(1.0, 4.0)
        params = (*params, (t_r, params[0][1], None))
        expect = ("autopilot parameters",)
        t_off = t_r
        duration = max(duration, t_r + (RESTORE_S[spec.airframe]))
    else:
        raise ValueError(f"unknown drill kind {kind!r}; choose one of {KINDS}")
    script = Script(
        f"{kind} {index:04d}", start, attack, t_on, t_off, expect, behave=behave,
        must_trigger=must, start_heading=heading, duration_s=duration, air_start=True,
        handover_s=t_h, link_cut=link_cut, params=params, expect_yield=expect_yield, kind=kind,
        after_yield_s=8.0 if not fw else 25.0,
        must_recover=recover and kind != "param_sabotage" and not (fw and kind == "wind"),
    )  # fmt: skip
    plan = FaultPlan(wind=wind, events=tuple(events))
    return CampaignDrill(script, plan, spec.airframe, kind, index, spec)


def shift_spec(spec: EnvelopeSpec, offset_ne: np.ndarray) -> EnvelopeSpec:
    """The same constraint set with every fence and zone moved by offset_ne (2,) [m] (the
    home radius stays about home)."""
    off = np.asarray(offset_ne, float)
    mv = lambda zs: tuple(Zone(z.name, z.points + off) for z in zs)  # noqa: E731
    return dataclasses.replace(spec, inclusions=mv(spec.inclusions), exclusions=mv(spec.exclusions),
                               source=f"{spec.source} moved by {off.round(1).tolist()} m")  # fmt: skip


def campaign(spec: EnvelopeSpec, p: DrillParams, n: int, seed: int) -> list[CampaignDrill]:
    """n drills for the airframe of `spec`, the kinds in turn."""
    out = []
    for i in range(n):
        rng = drill_rng(seed, spec.airframe, i)
        out.append(make_drill(drill_kind(spec.airframe, i), i, rng, spec, p))
    return out


def make_vehicle(drill: CampaignDrill, seed: int):
    """The autopilot a campaign drill flies: in the air at its start, with its fault plan; the
    fixed-wing with the drill's fence uploaded (as a mission would), so that its own HOLD
    circle — after a link loss the net cannot command through — is one that fits inside."""
    from skyherd.flight.airframes_registry import autopilot_class, make_autopilot

    if drill.airframe == "quadrotor":
        cls = autopilot_class("quadrotor")
        return cls(seed=seed, faults=drill.faults, start_pos_ned=tuple(drill.script.start_ned))
    from skyherd.safety.fence import vehicle_fence

    ap = make_autopilot("fixedwing", seed=seed, faults=drill.faults)
    ap.set_fence(vehicle_fence(drill.spec))  # the vehicle's own last line: its HOLD fits it
    ap.drain_status()
    return ap


# ---- what a campaign proves: an upper bound on the breach probability ------------------------
CONFIDENCE = 0.95


def breach_upper_bound(breaches: int, drills: int, confidence: float = CONFIDENCE) -> float:
    """One-sided Clopper–Pearson upper bound on the breach probability after `breaches` in
    `drills` independent drills: the p at which seeing <= breaches has probability 1 −
    confidence. 0 of n: 1 − (1 − confidence)^(1/n) in closed form; otherwise the beta
    quantile Beta(confidence; k + 1, n − k). No drills: 1 (nothing shown)."""
    if not (0 <= breaches <= drills) or not 0.0 < confidence < 1.0:
        raise ValueError(f"need 0 <= breaches <= drills and 0 < confidence < 1, got "
                         f"{breaches} of {drills} at {confidence}")  # fmt: skip
    if drills == 0 or breaches == drills:
        return 1.0
    if breaches == 0:
        return 1.0 - (1.0 - confidence) ** (1.0 / drills)
    from scipy.stats import beta

    return float(beta.ppf(confidence, breaches + 1, drills - breaches))


def drills_needed(bound: float, confidence: float = CONFIDENCE) -> int:
    """The fewest drills that, all without a breach, bound the breach probability at `bound`:
    the least n with 1 − (1 − confidence)^(1/n) <= bound (2,995 for 1e-3 at 95 %)."""
    if not 0.0 < bound < 1.0:
        raise ValueError(f"the target bound must be within (0, 1), got {bound}")
    n = math.ceil(math.log(1.0 - confidence) / math.log1p(-bound))
    while n > 1 and breach_upper_bound(0, n - 1, confidence) <= bound:  # rounding
        n -= 1
    while breach_upper_bound(0, n, confidence) > bound:
        n += 1
    return n
