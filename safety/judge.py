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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from safety.envelope import NZ, EnvelopeSpec, SignedDistance

NET_MODES = ("OFFBOARD", "HOLD")  # the modes the net flies in (safety.authority.NET_MODES)


@dataclass(frozen=True)
class JudgeParams:
    """The judge's thresholds."""

    airborne_m: float = 0.5  # truth altitude above home beyond this = in the air [m]
    landed_m: float = 0.3  # truth altitude above home at the end at most this = landed [m]
    frame_fraction_min: float = 0.9  # frames received / rendered in the AI phase, at least
    camera_gap_max_s: float = 1.0  # longest gap between good frames (the net's camera timeout) [s]
    camera_catch_s: float = 0.2  # the net's detection time after the timeout (a tick + margin) [s]
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


@dataclass(frozen=True)
class Check:
    name: str
    ok: bool
    figure: str  # the measured figure, e.g. "closest clearance −8.6 m at t = 41.2 s"
    reason: str  # why it passed or failed, in words


def judge(truth: Truth, spec: EnvelopeSpec, changes: Sequence[ModeChange],
          ai_window: tuple[float, float] | None, frame_t: Sequence[float] | None,
          rendered: int, ending: Ending, net_modes: Sequence[tuple[float, str]] = (),
          p: JudgeParams = JudgeParams(), received: int | None = None) -> list[Check]:  # fmt: skip
    """Every check, in order (module docstring). ai_window: (hand-over, end of the net's
    authority) [s], None when the net never had the vehicle; frame_t: the tick times of the
    good frames the companion received (None: the mission flies without a camera); rendered:
    the frames the simulator rendered in the AI window (one per world.csv row); net_modes: the
    net's switches (t, to: "ai" | "fallback" | "pid"), events.jsonl; "ai" from the hand-over;
    received: the good frames that arrived in the AI window when more than `frame_t` holds (a
    free-running companion takes the newest frame per tick and skips the others)."""
    return [
        fence_check(truth, spec, ai_window if p.floor else None, p),
        armed_check(truth, changes, p),
        modes_check(changes),
        camera_check(frame_t, ai_window, rendered, net_modes, p, received),
        end_check(truth, ending, p),
        Check(
            "mission",
            ending.outcome == "completed",
            ending.outcome,
            ending.reason or "the mission ran to its end",
        ),  # fmt: skip
    ]


def first_failed(checks: Sequence[Check]) -> Check | None:
    return next((c for c in checks if not c.ok), None)


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


def clearances(truth: Truth, spec: EnvelopeSpec,
               ai_window: tuple[float, float] | None) -> tuple[np.ndarray, list[str]]:  # fmt: skip
    """Per truth sample: the clearance [m] (< 0: beyond) to the nearest boundary it is judged
    against, and that boundary's name. Horizontal: fence, exclusion zones and home radius (the
    exact segment distance of safety.envelope.SignedDistance inside, its row measure outside);
    vertical: the ceiling always, the floor inside `ai_window` only."""
    signed = SignedDistance(spec)
    lim = spec.limits
    mid = -0.5 * (lim.floor_m + lim.ceiling_m)
    names = _ring_names(spec)
    out, which = np.empty(len(truth.t)), []
    for i, (t, p) in enumerate(zip(truth.t, truth.pos_ned)):
        beyond = signed.geometry.distance_outside(np.array([p[0], p[1], mid]))
        if beyond > 0 or not math.isfinite(beyond):
            c_h, w_h = -beyond, _outside_name(signed, p)
        else:
            q = p[:2]
            s = np.clip(np.einsum("ij,ij->i", q - signed.a, signed.ab) / signed.ab2, 0.0, 1.0)
            d = np.hypot(*(signed.a + s[:, None] * signed.ab - q).T)
            k = int(np.argmin(d)) if len(d) else -1
            c_h, w_h = (float(d[k]), names[k]) if k >= 0 else (math.inf, "")
        alt = -float(p[2])
        cands = [(c_h, w_h), (lim.ceiling_m - alt, "ceiling")]
        if ai_window is not None and ai_window[0] <= t <= ai_window[1]:
            cands.append((alt - lim.floor_m, "floor"))
        c, w = min(cands, key=lambda x: x[0])
        out[i] = c
        which.append(w)
    return out, which


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


def fence_check(truth: Truth, spec: EnvelopeSpec, ai_window, p: JudgeParams) -> Check:
    air = _airborne(truth, p)
    if not air.any():
        return Check("fence", True, "never airborne", "no truth sample in the air")
    c, which = clearances(truth, spec, ai_window)
    idx = np.flatnonzero(air)
    k = int(idx[np.argmin(c[idx])])
    fig = f"closest clearance {c[k]:+.2f} m at t = {truth.t[k]:.1f} s ({which[k]})"
    if c[k] >= 0:
        return Check("fence", True, fig, f"inside the envelope on all {len(idx)} airborne samples")
    n_out = int(np.sum(c[idx] < 0))
    return Check("fence", False, fig, f"the truth was beyond {which[k]} on {n_out} of "
                 f"{len(idx)} airborne samples (constraint set {spec.name} {spec.version})")  # fmt: skip


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


def modes_check(changes: Sequence[ModeChange]) -> Check:
    judged = [c for c in changes if c.by_companion is not None]
    foreign = [c for c in judged if not c.by_companion]
    if not foreign:
        return Check("modes", True, f"{len(judged)} changes in the AI phase, all the companion's",
                     "every mode change in the AI phase was asked for by the net")  # fmt: skip
    i = judged.index(foreign[0])
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
    if ending.land:
        ok = alt <= p.landed_m and not armed
        return Check("end", ok, fig, "landed and disarmed" if ok else "not landed and disarmed")
    ok = armed and alt > p.airborne_m and mode in NET_MODES
    why = "in its documented end: armed in the air in the net's mode (no landing)"
    return Check("end", ok, fig, why if ok else "not " + why.split(": ", 1)[1])
