"""The judge: did a flight end well, on the simulator's truth and the companion's records?

Pure (no I/O, no clock): flights (`skyherd fly`'s report) and drills pass in what they have.
`judge(...)` returns the checks in a fixed order; a flight is "completed" only when every one
passes, and the first that fails is the one named:

  fence     the truth never left the fence nor entered an exclusion zone, and stayed under
            the ceiling, on every sample while airborne; above the floor in the AI phase
            (take-off and landing cross the floor by design). Clearance ≥ 0 m.
  armed     never disarmed in the air (truth samples, and every arming change the companion saw).
  modes     every mode or arming change in the AI phase was one the companion asked for.
  camera    camera frames arrived at their rate through the AI phase: every gap longer than the
            net's camera timeout (+ the detection time `camera_catch_s`) caught by the net (the
            net not in "ai" once the timeout ran out: a lost camera is a net event and a
            fallback, not a blind flight); outside those gaps ≥ `frame_fraction_min` of the
            frames the simulator rendered arrived; and the caught gaps together ≤
            `lost_fraction_max` of the AI phase (a flight held by the net for want of a camera
            for most of its AI phase did not do its job, however safely).
  end       landed (truth altitude ≤ `landed_m`) and disarmed; or, for a flight that ends in
            the air by design (the fixed-wing orbit with --orbit-no-land: docs/orbit.md), armed,
            airborne and in one of the net's modes.
  mission   the companion's mission ran to its end (its own outcome).

A drill (safety.drills, the campaign, mission.drill_link) is judged by the same function with
what it demands of the net beyond a flight (`Expect`) and the net's own record (`NetRecord`):
the truth is the net's to answer for up to `NetRecord.answers_until` (a yield + the stopping
time + safety.drills.RUN_ON_S; after a yield to RTL / LAND only on the braking path it handed
over, `answered`), the autopilot's own failsafe may take over (the faults are injected on
purpose) but never be undone, the drill ends in the air, and three checks follow:

  failsafe  the autopilot's failsafe took over where the drill expects it; after the yield its
            own HOLD stayed inside the fence (its RTL / LAND path home is reported, not failed:
            the net must not undo it, and the line home is the mission planner's).
  caught    the net caught the violation the drill is about: a fallback or projection whose
            reason names it (or the expected yield).
  recovered the AI flies again at the end (unless the autopilot took over), and after a
            client restored a sabotaged parameter the net re-checked and handed back.

`verdict(checks)` is the one verdict line for both: "completed", or "failed: <the first failed
check>: <figure>: <reason>".
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from skyherd.safety.envelope import NZ, EnvelopeSpec, SignedDistance

NET_MODES = ("OFFBOARD", "HOLD")  # the modes the net flies in (safety.authority.NET_MODES)


@dataclass(frozen=True)
class JudgeParams:
    """The judge's thresholds."""

    airborne_m: float = 0.5  # truth altitude above home beyond this = in the air [m]
    landed_m: float = 0.3  # truth altitude above home at the end at most this = landed [m]
    frame_fraction_min: float = 0.9  # frames received / rendered in the AI phase, at least
    camera_gap_max_s: float = 1.0  # longest gap between good frames (the net's camera timeout) [s]
    camera_catch_s: float = 0.3  # the net's detection after the timeout [s]: the frame taken at the
    # next tick (<= 0.1 s), the loss seen at the tick after the timeout (<= 0.1 s), and free-running
    # a frame's delivery (measured 0.116 s at load: the net switched 1.216 s after the last frame)
    lost_fraction_max: float = 0.5  # the camera lost (caught gaps) at most this of the AI phase
    floor: bool = True  # judge the floor in the AI phase (False: a mission without a net)


@dataclass(frozen=True)
class Truth:
    """The simulator's truth (world.csv): t (n,) [s], pos_ned (n, 3) [m], armed (n,), mode (n,)."""

    t: np.ndarray
    pos_ned: np.ndarray
    armed: np.ndarray
    mode: tuple[str, ...]

    @staticmethod
    def from_rows(rows: Sequence[dict]) -> Truth:
        """From world.csv rows as read by csv.DictReader (t, north, east, down, mode, armed);
        a row that does not parse (the last one, cut by a kill) is left out."""
        rows = [r for r in rows if _parses(r)]
        t = np.array([float(r["t"]) for r in rows], dtype=float)
        pos = np.array([[float(r["north"]), float(r["east"]), float(r["down"])] for r in rows],
                       dtype=float).reshape(-1, 3)  # fmt: skip
        armed = np.array([str(r.get("armed", "0")).strip() in ("1", "True") for r in rows], bool)
        return Truth(t, pos, armed, tuple(str(r.get("mode", "")) for r in rows))


def _parses(row: dict) -> bool:
    try:
        return all(math.isfinite(float(row[k])) for k in ("t", "north", "east", "down"))
    except (KeyError, TypeError, ValueError):
        return False


@dataclass(frozen=True)
class ModeChange:
    """One change of the autopilot's (mode, armed) as the companion saw it (modes.jsonl).
    by_companion: True / False in the AI phase (asked for by the net or not); None outside it
    (the take-off and landing steps own the modes then)."""

    t: float
    mode: str
    armed: bool
    by_companion: bool | None = None
    alt_m: float = math.nan  # the companion's altitude above home when it arrived [m]


@dataclass(frozen=True)
class Ending:
    """How the flight ended, as far as the truth cannot say: the mission's own outcome, and
    whether it was meant to land."""

    outcome: str = "completed"
    reason: str = ""
    land: bool = True
    failsafe: str = ""  # a drill: the autopilot mode the net yielded to ("" = none)
    # the autopilot's documented end of a landing it does not fly to the ground, e.g. "RTL"
    # (ArduPlane has no LAND mode: hil.autopilots.ArduPlaneProfile.end_mode); "" = landed
    end_mode: str = ""


@dataclass(frozen=True)
class Expect:
    """What a drill demands of the net beyond a flight's checks (safety.drills.Script)."""

    reasons: tuple[str, ...] = ("",)  # a fallback / projection reason contains one ("" = any)
    catch: bool = True  # the net must catch (else the reasons are not demanded)
    failsafe: bool = False  # the autopilot's own failsafe must take over (and stand)
    recover: bool = True  # the AI flies again at the end, unless the autopilot took over
    restore_t: float = math.nan  # a client restored a sabotaged parameter [s after hand-over]


@dataclass(frozen=True)
class NetRecord:
    """What the net did in a drill, from its own records (supervisor, authority, guard)."""

    reasons: tuple[str, ...] = ()  # every reason it gave for a fallback, PID or projection
    yielded: str = ""  # the autopilot mode it yielded to ("" = never)
    t_yield: float = math.nan
    answers_until: float = math.inf  # it answers for the truth up to this time [s]
    end_mode: str = "ai"  # its mode at the end: ai | fallback | pid
    ai_after_restore: float = math.nan  # back in ai, parameters consistent, after the
    # restore [s after the hand-over]
    tolerance_m: float = 0.0  # the constraint set's breach_tolerance_m


@dataclass(frozen=True)
class Check:
    name: str
    ok: bool
    figure: str  # the measured figure, e.g. "closest clearance −8.6 m at t = 41.2 s"
    reason: str  # why it passed or failed, in words
    value: float = math.nan  # the figure's number where a caller needs it (fence: clearance [m])


def judge(truth: Truth, spec: EnvelopeSpec, changes: Sequence[ModeChange],
          ai_window: tuple[float, float] | None, frame_t: Sequence[float] | None,
          rendered: int, ending: Ending, net_modes: Sequence[tuple[float, str]] = (),
          p: JudgeParams = JudgeParams(), received: int | None = None,
          expect: Expect | None = None, net: NetRecord | None = None) -> list[Check]:  # fmt: skip
    """Every check, in order (module docstring). ai_window: (hand-over, end of the net's
    authority) [s], None when the net never had the vehicle; frame_t: the tick times of the
    good frames the companion received (None: the mission flies without a camera); rendered:
    the frames the simulator rendered in the AI window (one per world.csv row); net_modes: the
    net's switches (t, to: "ai" | "fallback" | "pid"), events.jsonl; "ai" from the hand-over;
    received: the good frames that arrived in the AI window when more than `frame_t` holds (a
    free-running companion takes the newest frame per tick and skips the others).
    expect, net: a drill's demands and the net's record (both, or neither: a flight)."""
    if (expect is None) != (net is None):
        raise ValueError("a drill is judged with both its Expect and its NetRecord")
    drill = expect is not None
    c, which = clearances(truth, spec, ai_window if p.floor else None, net)
    checks = [
        fence_check(truth, spec, c, which, p, net),
        armed_check(truth, changes, p),
        modes_check(changes, failsafe_ok=drill),
        camera_check(frame_t, ai_window, rendered, net_modes, p, received),
        end_check(truth, ending, p),
        Check(
            "mission",
            ending.outcome == "completed",
            ending.outcome,
            ending.reason or "the mission ran to its end",
        ),  # fmt: skip
    ]
    if drill:
        checks += [failsafe_check(truth, spec, c, which, expect, net, p),
                   caught_check(expect, net), recovered_check(expect, net)]  # fmt: skip
    return checks


def first_failed(checks: Sequence[Check]) -> Check | None:
    return next((c for c in checks if not c.ok), None)


def failed_text(c: Check) -> str:
    return f"{c.name}: {c.figure}: {c.reason}"


def verdict(checks: Sequence[Check]) -> str:
    """The verdict: "completed", or "failed: " + the first failed check, its figure and reason."""
    f = first_failed(checks)
    return "completed" if f is None else f"failed: {failed_text(f)}"


# ---- the checks ----------------------------------------------------------------------------
def height(truth: Truth) -> np.ndarray:
    """Height above the ground [m]: the altitude above the first sample's when the vehicle
    starts disarmed (on the ground: a fixed-wing's reference point sits ~1 m up on its gear),
    else above home."""
    alt = -truth.pos_ned[:, 2]
    ground = alt[0] if len(alt) and not truth.armed[0] else 0.0
    return alt - ground


def _airborne(truth: Truth, p: JudgeParams) -> np.ndarray:
    return height(truth) > p.airborne_m if len(truth.t) else np.zeros(0, bool)


def clearances(truth: Truth, spec: EnvelopeSpec, ai_window: tuple[float, float] | None,
               net: NetRecord | None = None) -> tuple[np.ndarray, Callable[[int], str]]:  # fmt: skip
    """Per truth sample: the clearance [m] (< 0: beyond) to the nearest boundary it is judged
    against, and a function naming that boundary for a sample. Horizontal: fence, exclusion
    zones and home radius (the exact segment distance of safety.envelope.SignedDistance inside,
    its row measure outside); vertical: the ceiling always, the floor inside `ai_window` only
    (a drill's: up to `net.answers_until`; the autopilot's own flight after it crosses the
    floor by design). Vectorized: a drill's truth has a sample every autopilot step."""
    signed = SignedDistance(spec)
    lim = spec.limits
    pos = np.asarray(truth.pos_ned, float).reshape(-1, 3)
    t = np.asarray(truth.t, float)
    z = np.zeros((len(t), NZ))
    z[:, 0:2] = pos[:, :2]
    z[:, 2] = -0.5 * (lim.floor_m + lim.ceiling_m)
    beyond = worst_rows(signed.geometry, z)
    c_h = np.where(np.isfinite(beyond), -beyond, -math.inf)
    inside = np.flatnonzero(c_h >= 0)
    seg = np.full(len(t), -1, dtype=int)
    for k in range(0, len(inside), 2048):  # the exact distance to the nearest edge, in chunks
        idx = inside[k : k + 2048]
        if not len(signed.a):
            c_h[idx] = math.inf
            continue
        q = pos[idx, None, :2]
        u = np.clip(np.einsum("kij,ij->ki", q - signed.a, signed.ab) / signed.ab2, 0.0, 1.0)
        d = np.hypot(*np.moveaxis(signed.a + u[..., None] * signed.ab - q, -1, 0))
        seg[idx] = np.argmin(d, axis=1)
        c_h[idx] = d[np.arange(len(idx)), seg[idx]]
    alt = -pos[:, 2]
    c_floor = np.full(len(t), math.inf)
    if ai_window is not None:
        t1 = ai_window[1] if net is None else max(ai_window[1], min(net.answers_until, t[-1]))
        w = (t >= ai_window[0]) & (t <= t1)
        c_floor[w] = alt[w] - lim.floor_m
    cands = np.stack([c_h, lim.ceiling_m - alt, c_floor])
    kind = np.argmin(np.where(np.isnan(cands), -math.inf, cands), axis=0)
    c = cands[kind, np.arange(len(t))]
    names = _ring_names(spec)

    def name(i: int) -> str:
        if kind[i] == 1:
            return "ceiling"
        if kind[i] == 2:
            return "floor"
        return names[seg[i]] if seg[i] >= 0 else _outside_name(signed, pos[i])

    return c, name


def worst_rows(geo, z: np.ndarray) -> np.ndarray:
    """Envelope.worst for many states z (n, NZ) at once (numpy): the union-of-polyhedra test,
    NaN where a state is not finite."""
    r = z @ geo.A.T - geo.b
    w = r[:, : geo.n_base].max(axis=1) if geo.n_base else np.full(len(r), -math.inf)
    if geo.n_piece_end > geo.n_base:
        pieces = np.maximum.reduceat(r[:, geo.n_base : geo.n_piece_end], geo.piece_starts, axis=1)
        w = np.maximum(w, pieces.min(axis=1))
    if geo.m > geo.n_piece_end:
        zones = np.minimum.reduceat(r[:, geo.n_piece_end :], geo.zone_starts, axis=1)
        w = np.maximum(w, zones.max(axis=1))
    w[~np.isfinite(r).all(axis=1)] = math.nan
    return w


def _ring_names(spec: EnvelopeSpec) -> list[str]:
    """One name per edge of SignedDistance's rings (inclusions, exclusions, home radius)."""
    names: list[str] = []
    for z in spec.inclusions:
        names += [f"fence '{z.name}'"] * len(z.points)
    for z in spec.exclusions:
        names += [f"exclusion zone '{z.name}'"] * len(z.points)
    if spec.limits.home_radius_m > 0:
        names += [f"home radius {spec.limits.home_radius_m:g} m"] * spec.limits.circle_sides
    return names


def _outside_name(signed: SignedDistance, p: np.ndarray) -> str:
    """Which area a position beyond the horizontal boundary violates (the worst row's name)."""
    z = np.zeros(NZ)
    z[0:2] = p[:2]
    lim = signed.spec.limits
    z[2] = -0.5 * (lim.floor_m + lim.ceiling_m)
    bad = signed.geometry.violated(z)
    return bad[0][0] if bad else "fence"


def fence_check(truth: Truth, spec: EnvelopeSpec, c: np.ndarray, name: Callable[[int], str],
                p: JudgeParams, net: NetRecord | None = None) -> Check:  # fmt: skip
    """Airborne samples (a drill's: those the net answers for, `answered`) at least -tolerance
    inside."""
    air = _airborne(truth, p)
    if net is not None:
        air &= answered(truth, spec, net)
    if not air.any():
        return Check("fence", True, "never airborne", "no truth sample in the air", math.inf)
    tol = net.tolerance_m if net is not None else 0.0
    idx = np.flatnonzero(air)
    k = int(idx[np.argmin(c[idx])])
    fig = f"closest clearance {c[k]:+.2f} m at t = {truth.t[k]:.1f} s ({name(k)})"
    if c[k] >= -tol:
        return Check("fence", True, fig, f"inside the envelope on all {len(idx)} airborne "
                     "samples", float(c[k]))  # fmt: skip
    n_out = int(np.sum(c[idx] < -tol))
    return Check("fence", False, fig, f"the truth was beyond {name(k)} on {n_out} of "
                 f"{len(idx)} airborne samples (constraint set {spec.name} {spec.version})",
                 float(c[k]))  # fmt: skip


def armed_check(truth: Truth, changes: Sequence[ModeChange], p: JudgeParams) -> Check:
    air = _airborne(truth, p)
    bad = np.flatnonzero(air & ~truth.armed)
    h = height(truth)

    def at(c: ModeChange) -> float:  # the truth's height then; the companion's without truth
        return float(np.interp(c.t, truth.t, h)) if len(h) else c.alt_m

    seen = [c for c in changes if not c.armed and at(c) > p.airborne_m]
    if len(bad):
        k = int(bad[0])
        fig = f"disarmed at {height(truth)[k]:.1f} m, t = {truth.t[k]:.1f} s"
        return Check("armed", False, fig, f"disarmed in the air on {len(bad)} truth samples")
    if seen:
        c = seen[0]
        fig = f"disarmed at {at(c):.1f} m, t = {c.t:.1f} s (heartbeat)"
        return Check("armed", False, fig, "the companion saw a disarm in the air")
    return Check("armed", True, f"armed on all {int(air.sum())} airborne samples",
                 "never disarmed in the air")  # fmt: skip


def _change_text(c: ModeChange) -> str:
    return f"{c.mode}{'' if c.armed else ' disarmed'} at t = {c.t:.2f} s"


def modes_check(changes: Sequence[ModeChange], failsafe_ok: bool = False) -> Check:
    """Every change in the AI phase the companion's. failsafe_ok (a drill: faults injected on
    purpose): the autopilot's own change may end the AI phase, and the net never undoes it."""
    judged = [c for c in changes if c.by_companion is not None]
    foreign = [c for c in judged if not c.by_companion]
    if not foreign:
        return Check("modes", True, f"{len(judged)} changes in the AI phase, all the companion's",
                     "every mode change in the AI phase was asked for by the net")  # fmt: skip
    i = judged.index(foreign[0])
    if failsafe_ok:
        undone = [c for c in judged[i + 1 :] if c.by_companion]
        if not undone:
            return Check("modes", True, f"{len(judged)} changes; the autopilot's own "
                         f"{_change_text(foreign[0])}, not undone",
                         "the net's changes, then the autopilot's failsafe, which it never undid")  # fmt: skip
        return Check("modes", False, f"{_change_text(foreign[0])}, undone: {_change_text(undone[0])}",
                     f"the net overrode the autopilot's own mode {len(undone)} times")  # fmt: skip
    after = f", then {_change_text(judged[i + 1])}" if i + 1 < len(judged) else ""
    return Check("modes", False, f"{_change_text(foreign[0])}{after}",
                 f"mode change not the companion's ({len(foreign)} of {len(judged)} in the AI phase)")  # fmt: skip


def net_mode_at(net_modes: Sequence[tuple[float, str]], t: float) -> str:
    """The net's mode at t from its switches (t, to), "ai" before the first."""
    mode = "ai"
    for t_s, to in sorted(net_modes):
        if t_s > t + 1e-9:
            break
        mode = to
    return mode


def camera_check(frame_t: Sequence[float] | None, ai_window, rendered: int,
                 net_modes: Sequence[tuple[float, str]], p: JudgeParams,
                 received: int | None = None) -> Check:  # fmt: skip
    if frame_t is None:
        return Check("camera", True, "no camera", "this mission flies without a camera")
    if ai_window is None:
        return Check("camera", True, "no AI phase", "the net never had the vehicle")
    t0, t1 = ai_window
    got = np.sort(np.array([t for t in frame_t if t0 - 1e-9 <= t <= t1 + 1e-9], dtype=float))
    edges = np.concatenate([[t0], got, [t1]])
    gaps = np.diff(edges)
    k = int(np.argmax(gaps))
    n = len(got) if received is None else max(received, len(got))
    late = p.camera_gap_max_s + p.camera_catch_s
    long = [(float(g), float(a)) for g, a in zip(gaps, edges[:-1]) if g > late + 1e-9]
    blind = [(g, a) for g, a in long if net_mode_at(net_modes, a + late) == "ai"]
    lost_s = sum(g for g, _ in long)
    span = max(t1 - t0, 1e-9)
    expected = rendered * (1.0 - lost_s / span)  # rendered outside the caught gaps
    frac = n / expected if expected > 0.5 else 1.0
    fig = (f"{n} of {rendered} frames, longest gap {gaps[k]:.1f} s from t = {edges[k]:.1f} s, "
           f"camera lost {100 * lost_s / span:.0f} % of the AI phase")  # fmt: skip
    if blind:
        g, a = blind[0]
        return Check("camera", False, fig, f"blind: no frame for {g:.1f} s from t = {a:.1f} s "
                     f"and the net still in ai at {a + late:.1f} s (camera timeout "
                     f"{p.camera_gap_max_s:g} s)")  # fmt: skip
    if lost_s > p.lost_fraction_max * span:
        return Check("camera", False, fig, f"the camera lost for more than "
                     f"{100 * p.lost_fraction_max:.0f} % of the AI phase ({t0:.1f}-{t1:.1f} s): "
                     "held safely by the net, but not flown with a camera")  # fmt: skip
    if frac < p.frame_fraction_min:
        return Check("camera", False, fig, f"{100 * frac:.0f} % of the frames arrived while the "
                     f"camera counted as working (at least {100 * p.frame_fraction_min:.0f} %)")  # fmt: skip
    why = "the frames arrived at their rate through the AI phase"
    if long:
        why += f"; {len(long)} gap(s) beyond the camera timeout, each caught by the net"
    return Check("camera", True, fig, why)


def end_check(truth: Truth, ending: Ending, p: JudgeParams) -> Check:
    if not len(truth.t):
        return Check("end", False, "no truth", "the simulator wrote no world.csv rows")
    alt = float(height(truth)[-1]) + 0.0  # (+ 0.0: no "-0.00 m")
    armed, mode = bool(truth.armed[-1]), truth.mode[-1]
    fig = f"{alt:.2f} m, {'armed' if armed else 'disarmed'}, {mode} at t = {truth.t[-1]:.1f} s"
    if ending.failsafe:  # a drill the autopilot's failsafe took over: it ends where that flies
        return Check("end", True, fig, f"the autopilot's own {ending.failsafe} has the vehicle")
    if ending.land and ending.end_mode:
        ok = armed and alt > p.airborne_m and mode == ending.end_mode
        why = f"in its documented end: armed in the air in {ending.end_mode} (it does not land)"
        return Check("end", ok, fig, why if ok else "not " + why.split(": ", 1)[1])
    if ending.land:
        ok = alt <= p.landed_m and not armed
        return Check("end", ok, fig, "landed and disarmed" if ok else "not landed and disarmed")
    ok = armed and alt > p.airborne_m and mode in NET_MODES
    why = "in its documented end: armed in the air in the net's mode (no landing)"
    return Check("end", ok, fig, why if ok else "not " + why.split(": ", 1)[1])


# ---- a drill's checks ----------------------------------------------------------------------
FAILSAFE_PATH_MODES = ("RTL", "LAND")
"""The autopilot's own failsafe paths (straight line home, descent): reported, not failing."""


def answered(truth: Truth, spec: EnvelopeSpec, net: NetRecord) -> np.ndarray:
    """The truth samples a drill's net answers for: up to `net.answers_until` (its yield + its
    stop + safety.drills.RUN_ON_S: the momentum it handed over); after a yield to the autopilot's
    RTL / LAND, of those only the samples on its own stop. That stop is the straight braking
    path from the truth's position at the yield along its velocity there, as long as eq. 3's
    reach at the fastest horizontal speed s within react_s of the yield (react_s s +
    s^2 / (2 decel_h)), and margin_m (+ the breach tolerance) either side of it. A sample off
    that path, in RTL / LAND, is on the autopilot's own line home: reported (`own_flight`), not
    the net's. A vehicle that cannot stop (decel_h 0: a fixed-wing) answers for its whole window.
    Campaign seed 0, battery 43134: yielded 4 m beside the mast at 7 m/s, flying away from it;
    the RTL turned home through it 2 s later, 5 m off the braking path."""
    t = truth.t
    mask = t <= net.answers_until
    dyn, lim = spec.dynamics, spec.limits
    if net.yielded not in FAILSAFE_PATH_MODES or not math.isfinite(net.t_yield):
        return mask
    if dyn.decel_h_mps2 <= 0.0 or len(t) < 3:
        return mask
    xy = truth.pos_ned[:, :2]
    k = min(int(np.searchsorted(t, net.t_yield)), len(t) - 1)
    near = np.flatnonzero(np.abs(t - t[k]) <= dyn.react_s)
    lo, hi = max(near[0] - 1, 0), min(near[-1] + 2, len(t))
    v = np.gradient(xy[lo:hi], t[lo:hi], axis=0)  # the truth's horizontal velocity [m/s]
    speed = float(np.max(np.hypot(v[:, 0], v[:, 1])))
    if not math.isfinite(speed):  # repeated sample times: no velocity, the window is the net's
        return mask
    v_k = v[k - lo]
    n_k = float(np.hypot(*v_k))
    u = v_k / n_k if n_k > 1e-6 else np.zeros(2)
    reach = dyn.react_s * speed + speed * speed / (2.0 * dyn.decel_h_mps2)  # eq. 3
    rel = xy - xy[k]
    along = np.clip(rel @ u, 0.0, reach)
    off = np.hypot(*(rel - along[:, None] * u).T)  # distance to the braking path [m]
    own_path = (t > t[k]) & np.isin(truth.mode, FAILSAFE_PATH_MODES)
    return mask & ~(own_path & (off > lim.margin_m + net.tolerance_m))


def own_flight(truth: Truth, spec: EnvelopeSpec, c: np.ndarray, net: NetRecord,
               p: JudgeParams) -> tuple[float, str]:  # fmt: skip
    """The autopilot's own flight after the net stopped answering (a yield; `answered`): its
    worst excursion beyond the fence [m] (< 0: inside; -inf: none) and its mode there."""
    if not net.yielded:
        return -math.inf, ""
    own = _airborne(truth, p) & ~answered(truth, spec, net)
    if not own.any():
        return -math.inf, ""
    idx = np.flatnonzero(own)
    k = int(idx[np.argmin(c[idx])])
    return float(-c[k]), truth.mode[k]


def failsafe_check(truth: Truth, spec: EnvelopeSpec, c: np.ndarray, name: Callable[[int], str],
                   expect: Expect, net: NetRecord, p: JudgeParams) -> Check:  # fmt: skip
    if expect.failsafe and not net.yielded:
        return Check("failsafe", False, "the net never yielded",
                     "the autopilot's failsafe was expected to take over; the net never yielded")  # fmt: skip
    if not net.yielded:
        return Check("failsafe", True, "no failsafe", "the autopilot never took over")
    x, mode = own_flight(truth, spec, c, net, p)
    fig = f"yielded to {net.yielded} at t = {net.t_yield:.1f} s"
    if math.isfinite(x):
        fig += f"; its own flight {-x:+.2f} m from the fence at worst ({mode})"
    if x > net.tolerance_m and mode not in FAILSAFE_PATH_MODES:
        return Check("failsafe", False, fig, f"the autopilot's own {mode} after the yield left "
                     "the fence (the built-in vehicle fits its hold to the uploaded fence)")  # fmt: skip
    if x > net.tolerance_m:
        return Check("failsafe", True, fig, f"its own {mode} path crossed the fence: reported, "
                     "not failed (the autopilot's failsafe; the line home is the planner's)")  # fmt: skip
    return Check("failsafe", True, fig, "the autopilot's failsafe stood, inside the fence")


def caught_check(expect: Expect, net: NetRecord) -> Check:
    fig = f"first reason {net.reasons[0]!r}" if net.reasons else "no fallback or projection"
    if not expect.catch:
        return Check("caught", True, fig, "this drill demands no catch (it may stay off the rows)")
    hit = next((r for r in net.reasons if any(k in r for k in expect.reasons)), None)
    if hit is not None:
        return Check("caught", True, f"{hit!r}", f"the net caught it ({len(net.reasons)} reasons)")
    if expect.failsafe and net.yielded:
        return Check("caught", True, f"yielded to {net.yielded}",
                     "the autopilot's failsafe took over, as expected")  # fmt: skip
    return Check("caught", False, fig, f"expected a fallback or projection for {expect.reasons}, "
                 f"got {list(net.reasons) or 'none'}")  # fmt: skip


def recovered_check(expect: Expect, net: NetRecord) -> Check:
    fig = f"the net in {net.end_mode} at the end"
    if not math.isnan(expect.restore_t):
        if net.yielded:
            fig = f"waiting (yielded to {net.yielded})"
        elif not math.isnan(net.ai_after_restore):
            fig = f"handed back {net.ai_after_restore - expect.restore_t:.1f} s after the restore"
        else:
            return Check("recovered", False, "not handed back", "a client restored the sabotaged "
                         "parameter but the net did not hand back to the AI")  # fmt: skip
    if expect.recover and not expect.failsafe and not net.yielded and net.end_mode != "ai":
        return Check("recovered", False, fig, f"not recovered: {net.end_mode} at the end")
    if not expect.recover or expect.failsafe or net.yielded:
        return Check("recovered", True, fig, "not judged on the recovery (a failsafe, or "
                     "a drill that may end in the net's hold)")  # fmt: skip
    return Check("recovered", True, fig, "the AI flies again at the end")
