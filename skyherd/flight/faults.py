"""Faults in the simulation: wind, GPS glitch / drift / loss, baro offset, sensor noise, battery.

A `FaultPlan` (frozen, saved with the run) says what happens and when; a `FaultInjector`
plays it on the simulation clock with a seeded `numpy.random.Generator` passed in, so a run
is deterministic for its seed. The autopilots call `FaultInjector.update(t, dt)` once per
control step and fly on the *estimate* (truth + the GPS error it returns), as a real
autopilot flies on its EKF output; ground truth stays in the physics.

Models (all NED, SI):
  wind     w = mean + gust + Σ active wind events; gust: first-order Gauss-Markov per axis,
           g_{k+1} = a g_k + σ √(1 − a²) n_k, a = exp(−dt/τ) (flight.quadrotor.WindModel).
  gps_glitch  a step offset e_p = (n, e, d) [m] for the event's duration (not rejected by an
           innovation gate: the worst case, a spoofed or multipath fix).
  gps_drift   e_p grows at (v_n, v_e, v_d) [m/s] during the event, back to 0 when it ends.
  baro     a barometer offset: the estimate's altitude reads OFFSET [m] above the truth (its
           down error is −OFFSET) for the event's duration; the horizontal estimate is untouched.
  gps_loss    no fix: the estimate dead-reckons; its error grows from the loss on as
           e_v = b t, e_p = ½ b t² with an accelerometer bias b ~ N(0, σ_b²) per horizontal
           axis drawn at the loss (σ_b = DeadReckoning.accel_bias_std). The autopilot's rule
           (flight/multirotor/autopilot.py): valid for EKF2_NOAID_TOUT s, then LAND.
  noise    estimate noise: first-order Gauss-Markov on position (σ_p, τ_p) and velocity
           (σ_v, τ_v), the smoothed error an EKF output shows (not white GPS noise).
  battery  `battery@T:F` drops the remaining charge to F ∈ [0, 1] at T (a failing cell);
           `drain@T:W:D` draws W watts more for D s (heater, stuck motor).
  disarm   `disarm@T`: the autopilot is force-disarmed at T (a kill switch, or a ground
           station's COMPONENT_ARM_DISARM 0 with 21196); in the air the vehicle falls.
  rtl      `rtl@T[:D]`: the autopilot switches to RTL at T and, after D s, back to the mode it
           was in (a ground station's or an RC pilot's RTL and back); D omitted = stays in RTL.

Command line (`parse_fault_args`, the same flags for `skyherd sitl` and `skyherd sim`):
  --wind SPEED,FROM[,DOWN]  mean wind [m/s] blowing from FROM [deg clockwise from north]
                            (meteorological: 270 blows toward the east); DOWN [m/s] optional
  --gust STD[,TAU]          gust standard deviation [m/s] and correlation time [s] (2)
  --noise POS[,VEL]         estimate noise σ_p [m] (τ 1 s) and σ_v [m/s] (τ 0.5 s)
  --fault KIND@T[:ARGS][:DURATION]   (repeatable; DURATION [s] omitted = to the end)
      gps_glitch@30:20,0,0:5    +20 m north for 5 s from t = 30 s
      gps_drift@30:0.5,0,0:20   north error growing 0.5 m/s for 20 s
      gps_loss@30:10            no fix for 10 s (gps_loss@30 = for ever)
      baro@30:5:20              the altitude estimate 5 m high for 20 s
      wind@40:16,90:10          extra 16 m/s from the east for 10 s (a gust front)
      battery@60:0.06           charge drops to 6 % at t = 60 s
      drain@10:300:60           300 W more for 60 s
      disarm@25                 forced disarm at t = 25 s
      rtl@25.02:0.05            RTL at t = 25.02 s, the mode before it again at 25.07 s
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.wind import WindField, WindModel

KINDS = ("gps_glitch", "gps_drift", "gps_loss", "baro", "wind", "battery", "drain", "disarm", "rtl")
ESTIMATE_KINDS = ("gps_glitch", "gps_drift", "gps_loss", "baro")  # faults of the estimate
SWITCH_KINDS = ("disarm", "rtl")  # faults that act on the autopilot's arming or mode


class FaultSpecError(ValueError):
    """A fault flag or plan that cannot be used; the message says what to write instead."""


def wind_from(speed: float, from_deg: float, down: float = 0.0) -> tuple[float, float, float]:
    """NED wind vector [m/s] for `speed` blowing *from* `from_deg` (clockwise from north)."""
    a = math.radians(from_deg)
    return (-speed * math.cos(a), -speed * math.sin(a), down)


@dataclass(frozen=True)
class FaultEvent:
    """One timed fault. t0 [s sim]; duration [s] (None = to the end); vec (3,) or value."""

    kind: str
    t0: float
    duration: float | None = None
    vec: tuple[float, float, float] = (0.0, 0.0, 0.0)
    value: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise FaultSpecError(f"fault kind {self.kind!r}: choose one of {', '.join(KINDS)}")
        nums = [self.t0, *self.vec, self.value]
        if not all(math.isfinite(v) for v in nums) or self.t0 < 0:
            raise FaultSpecError(f"{self.kind}: time and values must be finite, t0 >= 0")
        if self.duration is not None and not (0 < self.duration < 1e9):
            raise FaultSpecError(f"{self.kind}: duration must be > 0 s (omit it for 'to the end')")
        if self.kind == "battery" and not 0.0 <= self.value <= 1.0:
            raise FaultSpecError(f"battery@T:F needs F in [0, 1], got {self.value}")
        if self.kind == "disarm" and self.duration is not None:
            raise FaultSpecError("disarm@T takes no duration: a disarm is for good")
        if self.kind == "drain" and not 0.0 <= self.value <= 1e5:
            raise FaultSpecError(f"drain@T:W:D needs 0 <= W <= 1e5 watts, got {self.value}")
        if self.kind == "baro" and not abs(self.value) <= 1000.0:
            raise FaultSpecError(f"baro@T:OFFSET needs |OFFSET| <= 1000 m, got {self.value}")

    def active(self, t: float) -> bool:
        return self.t0 <= t and (self.duration is None or t < self.t0 + self.duration)

    def to_text(self) -> str:
        """The command-line form (parse_fault_event(e.to_text()) == e)."""
        dur = "" if self.duration is None else f":{self.duration:g}"
        v = ",".join(f"{c:g}" for c in self.vec)
        if self.kind in ("gps_loss", "rtl"):
            return f"{self.kind}@{self.t0:g}{dur}"
        if self.kind == "disarm":
            return f"disarm@{self.t0:g}"
        if self.kind == "wind":
            sp = math.hypot(self.vec[0], self.vec[1])
            frm = math.degrees(math.atan2(-self.vec[1], -self.vec[0])) % 360.0
            return f"wind@{self.t0:g}:{sp:g},{frm:g},{self.vec[2]:g}{dur}"
        if self.kind in ("battery", "drain", "baro"):
            return f"{self.kind}@{self.t0:g}:{self.value:g}{dur}"
        return f"{self.kind}@{self.t0:g}:{v}{dur}"


@dataclass(frozen=True)
class SensorNoise:
    """Estimate noise: Gauss-Markov σ_p [m], τ_p [s] on position, σ_v [m/s], τ_v [s] on velocity."""

    pos_std: float = 0.0
    vel_std: float = 0.0
    pos_tau: float = 1.0
    vel_tau: float = 0.5

    def __post_init__(self) -> None:
        vals = (self.pos_std, self.vel_std, self.pos_tau, self.vel_tau)
        if not all(math.isfinite(v) for v in vals) or min(vals[:2]) < 0 or min(vals[2:]) <= 0:
            raise FaultSpecError("noise: std >= 0 and tau > 0, all finite")
        if self.pos_std > 50 or self.vel_std > 10:
            raise FaultSpecError("noise: position std <= 50 m and velocity std <= 10 m/s")


@dataclass(frozen=True)
class DeadReckoning:
    """Error growth without GPS: accelerometer bias σ_b [m/s²] per horizontal axis."""

    accel_bias_std: float = 0.05


@dataclass(frozen=True)
class FaultPlan:
    """Everything the simulation does to the vehicle; empty = calm air, perfect state."""

    wind: WindModel = field(default_factory=WindModel)
    noise: SensorNoise = field(default_factory=SensorNoise)
    events: tuple[FaultEvent, ...] = ()
    dead_reckoning: DeadReckoning = field(default_factory=DeadReckoning)

    @property
    def empty(self) -> bool:
        calm = self.wind.gust_std == 0.0 and not any(self.wind.mean_ned)
        quiet = self.noise.pos_std == 0.0 and self.noise.vel_std == 0.0
        return calm and quiet and not self.events

    @property
    def touches_estimate(self) -> bool:
        """True when the estimate can differ from the truth (GPS or baro faults, or noise)."""
        gps = any(e.kind in ESTIMATE_KINDS for e in self.events)
        return gps or self.noise.pos_std > 0.0 or self.noise.vel_std > 0.0

    def to_args(self) -> list[str]:
        """Command-line flags that rebuild this plan (recorded in config.json)."""
        out: list[str] = []
        w = self.wind.mean_ned
        if any(w):
            sp = math.hypot(w[0], w[1])
            frm = math.degrees(math.atan2(-w[1], -w[0])) % 360.0
            out += ["--wind", f"{sp:g},{frm:g},{w[2]:g}"]
        if self.wind.gust_std > 0:
            out += ["--gust", f"{self.wind.gust_std:g},{self.wind.gust_tau:g}"]
        if self.noise.pos_std > 0 or self.noise.vel_std > 0:
            out += ["--noise", f"{self.noise.pos_std:g},{self.noise.vel_std:g}"]
        for e in self.events:
            out += ["--fault", e.to_text()]
        return out


# ------------------------------------------------------------------------------- parsing
def _floats(text: str, what: str, n_min: int, n_max: int) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError as e:
        raise FaultSpecError(f"{what}: {text!r} is not a comma-separated list of numbers") from e
    if not n_min <= len(vals) <= n_max or not all(math.isfinite(v) for v in vals):
        raise FaultSpecError(f"{what}: need {n_min}..{n_max} finite numbers, got {text!r}")
    return vals


def parse_fault_event(text: str) -> FaultEvent:
    """`KIND@T[:ARGS][:DURATION]` → FaultEvent (see the module docstring)."""
    head, sep, rest = text.strip().partition("@")
    if not sep:
        raise FaultSpecError(
            f"--fault {text!r}: write KIND@T[:ARGS][:DURATION], e.g. gps_loss@30:10"
        )
    kind = head.strip()
    if kind not in KINDS:
        raise FaultSpecError(f"--fault {text!r}: kind must be one of {', '.join(KINDS)}")
    parts = rest.split(":")
    t0 = _floats(parts[0], f"--fault {text!r} time", 1, 1)[0]
    args = parts[1:]
    want = 0 if kind in ("gps_loss", "disarm", "rtl") else 1
    if len(args) < want or len(args) > want + 1:
        form = f"{kind}@T[:DURATION]" if want == 0 else f"{kind}@T:ARGS[:DURATION]"
        raise FaultSpecError(f"--fault {text!r}: write {form}")
    dur = None
    if len(args) > want:
        dur = _floats(args[-1], f"--fault {text!r} duration", 1, 1)[0]
    try:
        if kind in ("gps_loss", "disarm", "rtl"):
            return FaultEvent(kind, t0, dur)
        if kind in ("battery", "drain", "baro"):
            v = _floats(args[0], f"--fault {text!r}", 1, 1)[0]
            return FaultEvent(kind, t0, dur, value=v)
        if kind == "wind":
            sp, frm, *down = _floats(args[0], f"--fault {text!r} SPEED,FROM[,DOWN]", 2, 3)
            return FaultEvent(kind, t0, dur, vec=wind_from(sp, frm, down[0] if down else 0.0))
        v3 = _floats(args[0], f"--fault {text!r} N,E,D", 3, 3)
        return FaultEvent(kind, t0, dur, vec=(v3[0], v3[1], v3[2]))
    except FaultSpecError:
        raise
    except ValueError as e:
        raise FaultSpecError(f"--fault {text!r}: {e}") from e


def parse_fault_args(
    wind: str | None = None,
    gust: str | None = None,
    noise: str | None = None,
    faults: Sequence[str] = (),
    seed: int = 0,
) -> FaultPlan:
    """The flags' strings → FaultPlan; FaultSpecError (a ValueError) with a one-line reason."""
    mean = (0.0, 0.0, 0.0)
    if wind:
        sp, frm, *down = _floats(wind, "--wind SPEED,FROM[,DOWN]", 2, 3)
        if not 0.0 <= sp <= 60.0:
            raise FaultSpecError(f"--wind speed must be in [0, 60] m/s, got {sp:g}")
        mean = wind_from(sp, frm, down[0] if down else 0.0)
    g_std, g_tau = 0.0, 2.0
    if gust:
        g = _floats(gust, "--gust STD[,TAU]", 1, 2)
        g_std, g_tau = g[0], (g[1] if len(g) > 1 else 2.0)
        if not (0.0 <= g_std <= 20.0 and g_tau > 0):
            raise FaultSpecError(f"--gust: need 0 <= STD <= 20 m/s and TAU > 0 s, got {gust!r}")
    pn, vn = 0.0, 0.0
    if noise:
        n = _floats(noise, "--noise POS[,VEL]", 1, 2)
        pn, vn = n[0], (n[1] if len(n) > 1 else 0.0)
    try:
        wm = WindModel(mean_ned=mean, gust_std=g_std, gust_tau=g_tau, seed=seed)
    except ValueError as e:
        raise FaultSpecError(str(e)) from e
    try:
        sn = SensorNoise(pn, vn)
    except FaultSpecError as e:
        raise FaultSpecError(f"--noise {noise!r}: {e}") from None
    events = tuple(sorted((parse_fault_event(f) for f in faults or ()), key=lambda e: e.t0))
    return FaultPlan(wind=wm, noise=sn, events=events)


# ------------------------------------------------------------------------------- playing
class GpsError:
    """The estimate's error now: pv (6,) = pos (3,) [m] and vel (3,) [m/s] (views into pv);
    fix False while GPS is lost; lost_s: seconds since the fix was lost (0 with a fix)."""

    def __init__(self) -> None:
        self.pv = np.zeros(6)
        self.pos = self.pv[0:3]
        self.vel = self.pv[3:6]
        self.fix = True
        self.lost_s = 0.0


class FaultInjector:
    """Plays a FaultPlan. `update(t, dt)` → GpsError (arrays reused: copy to keep).

    rng: the seeded Generator all random draws (gusts excepted: WindModel has its seed) use.
    """

    def __init__(self, plan: FaultPlan, rng: np.random.Generator):
        self.plan = plan
        self.rng = rng
        self.wind = WindField(plan.wind)
        self.err = GpsError()
        self._n6 = np.zeros(6)  # noise states: position (3), velocity (3)
        self._noisy = plan.noise.pos_std > 0.0 or plan.noise.vel_std > 0.0
        self._noise_dt = -1.0
        self._a6 = np.zeros(6)
        self._b6 = np.zeros(6)
        self._loss_t: float | None = None
        self._bias = np.zeros(3)
        self._dr_p = np.zeros(3)  # error when the fix was lost
        self._fired: set[int] = set()
        self._switched: set[tuple[int, int]] = set()
        self._set_events(plan.events)
        self.touches_estimate = plan.touches_estimate
        self.calm = self.wind.calm and not self._wind_events

    def _set_events(self, events: Sequence[FaultEvent]) -> None:
        self._wind_events = tuple(e for e in events if e.kind == "wind")
        self._gps_events = tuple(
            (e, np.asarray(e.vec, dtype=float)) for e in events if e.kind in ESTIMATE_KINDS
        )
        self._battery_events = tuple(e for e in events if e.kind in ("battery", "drain"))
        self._switch_events = tuple(e for e in events if e.kind in SWITCH_KINDS)

    def shift(self, dt: float, t_now: float) -> None:
        """Move every timed event by dt [s]: a plan written relative to a hand-over whose
        time is known only in flight (the drills through the mission code, whose hand-over
        is when the companion's mission makes it). ValueError if an event already began."""
        if any(e.t0 <= t_now for e in self.plan.events):
            raise ValueError(f"a fault event began before t = {t_now:.3f} s: too late to move it")
        events = tuple(dataclasses.replace(e, t0=e.t0 + dt) for e in self.plan.events)
        self.plan = dataclasses.replace(self.plan, events=events)
        self._set_events(events)

    def wind_ned(self, t: float, dt: float) -> np.ndarray:
        """(3,) wind [m/s] NED acting over the next dt."""
        w = self.wind.sample(dt)
        for e in self._wind_events:
            if e.active(t):
                w = w + np.asarray(e.vec)
        return w

    def battery(self, t: float) -> tuple[float | None, float]:
        """(charge to drop to now or None, extra power now [W]) — each drop fires once."""
        drop, watts = None, 0.0
        for i, e in enumerate(self._battery_events):
            if e.kind == "battery" and t >= e.t0 and i not in self._fired:
                self._fired.add(i)
                drop = e.value if drop is None else min(drop, e.value)
            elif e.kind == "drain" and e.active(t):
                watts += e.value
        return drop, watts

    def switches(self, t: float) -> list[str]:
        """The arming / mode actions due at t, each once, in order: "disarm", "rtl" and
        "rtl_end" (back to the mode before the RTL)."""
        out = []
        for i, e in enumerate(self._switch_events):
            if t >= e.t0 and (i, 0) not in self._switched:
                self._switched.add((i, 0))
                out.append(e.kind)
            end = e.t0 + e.duration if e.duration is not None else math.inf
            if e.kind == "rtl" and t >= end and (i, 1) not in self._switched:
                self._switched.add((i, 1))
                out.append("rtl_end")
        return out

    def update(self, t: float, dt: float) -> GpsError:
        """The estimate's error at time t (dt: the step, for the noise processes)."""
        err = self.err
        pv = err.pv
        pv[:] = 0.0
        lost = False
        for e, vec in self._gps_events:
            if not e.active(t):
                continue
            if e.kind == "gps_glitch":
                err.pos += vec
            elif e.kind == "gps_drift":
                err.pos += vec * (t - e.t0)
                err.vel += vec
            elif e.kind == "baro":
                err.pos[2] -= e.value
            else:
                lost = True
        if lost:
            if self._loss_t is None:  # the accelerometer bias of this outage
                self._loss_t = t
                self._bias[:2] = self.rng.normal(0.0, self.plan.dead_reckoning.accel_bias_std, 2)
                self._dr_p[:] = err.pos
            tau = t - self._loss_t
            err.pos[:] = self._dr_p + (0.5 * tau * tau) * self._bias
            err.vel += tau * self._bias
            err.fix, err.lost_s = False, tau
        else:
            self._loss_t = None
            err.fix, err.lost_s = True, 0.0
        if self._noisy:
            if dt != self._noise_dt:  # a = exp(−dt/τ), b = σ √(1 − a²) per component
                n = self.plan.noise
                self._noise_dt = dt
                a_p, a_v = math.exp(-dt / n.pos_tau), math.exp(-dt / n.vel_tau)
                self._a6[:3], self._a6[3:] = a_p, a_v
                self._b6[:3] = n.pos_std * math.sqrt(1.0 - a_p * a_p)
                self._b6[3:] = n.vel_std * math.sqrt(1.0 - a_v * a_v)
            n6 = self._n6
            n6 *= self._a6
            n6 += self._b6 * self.rng.standard_normal(6)
            pv += n6
        return err


def apply_switches(ap, due: list[str]) -> None:
    """The disarm / rtl faults on an autopilot (`FaultInjector.switches`), as a kill switch or a
    ground station would: "disarm" forces a disarm, "rtl" switches to RTL remembering the mode
    (`ap._mode_before_rtl`), anything else ("back") returns to it."""
    from skyherd.flight.autopilot_api import FlightMode

    for what in due:
        if what == "disarm":
            ap._event("fault: forced disarm")
            ap.disarm(force=True)
        elif what == "rtl":
            ap._mode_before_rtl = ap._mode
            ap._event("fault: RTL")
            ap.set_mode(FlightMode.RTL)
        else:
            back = ap._mode_before_rtl
            ap._event(f"fault: back to {back.name}")
            ap.set_mode(back)
