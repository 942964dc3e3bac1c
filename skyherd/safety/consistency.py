"""Envelope ↔ autopilot consistency: the envelope's assumptions checked against the
autopilot's parameters, at start and on every PARAM_VALUE.

The envelope (safety.envelope eq. 3) assumes that within `react_s` of the last certified
command the vehicle starts braking at `decel_h_mps2` (a multirotor) or loiters on a circle no
wider than R(v_max) = v_max² / (g tan bank_max) (a fixed-wing). The autopilot decides whether
that is true. The rules, each with the parameter names of PX4 and ArduPilot:

  R1 offboard loss → hold.  With the companion's link cut the autopilot flies the last setpoint
     for t_loss (PX4 COM_OF_LOSS_T, ArduPilot GUID_TIMEOUT) before its own hold. The run-on
     beyond the envelope's reaction must fit in its margin:
         (t_loss + dt − react_s) · v_max <= margin_m                        (C1)
  R2 braking.  The hold brakes with at most g tan(tilt_max) (PX4 MPC_TILTMAX_AIR [deg],
     ArduPilot ANGLE_MAX [cdeg]) and, where the autopilot has one, its braking acceleration
     (PX4 MPC_ACC_HOR [m/s²], ArduPilot LOIT_BRK_ACCEL [cm/s²]); both >= decel_h_mps2. (C2)
  R3 position-mode speed.  The net certifies a position setpoint by the velocity it implies,
     clipped at SupervisorParams.pos_speed_max_mps; the autopilot's own limit (PX4
     MPC_XY_VEL_MAX, ArduPilot WPNAV_SPEED [cm/s]) must not be higher.   (C3)
  R4 fixed-wing loiter.  The hold circle (PX4 NAV_LOITER_RAD, 0 = V_trim²/(g tan 0.7 φ_lim);
     ArduPilot WP_LOITER_RAD) must not exceed R(v_max), and the bank limit (FW_R_LIM [deg],
     ArduPilot ROLL_LIMIT_DEG) must reach the envelope's bank_max.       (C4)
  R5 offboard-loss action (PX4 COM_OBL_RC_ACT where present): one that brakes or returns
     (0 position, 3 return, 4 land, 5 hold); altitude/manual modes drift.   (C5)
  R6 fixed-wing climb and sink.  The net certifies a position setpoint by the climb it implies,
     clipped at the envelope's climb_mps / descent_mps; the autopilot's height controller
     climbs and sinks at up to its own limits (ArduPlane TECS_CLMB_MAX / TECS_SINK_MAX, PX4
     FW_T_CLMB_MAX / FW_T_SINK_MAX [m/s]), which must not be higher.        (C6)
  R7 fixed-wing bank.  The envelope's attitude rows stop the AI at |roll| > attitude_max_rad;
     an autopilot allowed to bank further (FW_R_LIM, ROLL_LIMIT_DEG) trips them in its own
     turns (measured: ArduPlane's stock 65° reached 50° returning from a recovery). Its limit
     must keep BANK_OVERSHOOT_DEG below the attitude row.                    (C7)
     `agreeing_values` gives the values a fixed-wing mission sets by itself to agree (C6, C7);
     `required_values` every value that agrees (`--configure-autopilot`).

A parameter that is absent is not checked (an autopilot without it); a value that is not
finite is a mismatch. `ParamGuard` keeps the parameters it has seen, the problems now and each
parameter's last value that broke no rule: a parameter someone sets to break a rule in flight
is refused (the net's fallback while it disagrees) *and set back* (`restores`: PARAM_SET to that
value until the PARAM_VALUE echo agrees), so that the autopilot's own failsafes — its hold
circle, its link-loss time — fly safe parameters when the net yields to them (docs/safety.md,
Run 7: a sabotaged NAV_LOITER_RAD flown by the offboard-loss HOLD beyond the fence).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from skyherd.flight.geo import GRAVITY
from skyherd.runio.constants import POS_SPEED_MAX_MPS
from skyherd.safety.envelope import EnvelopeSpec

PX4_OBL_OK = {0: "position", 3: "return", 4: "land", 5: "hold"}
RESTORE_RETRY_S = 1.0  # a restore whose echo has not come is sent again after this long [s]
BANK_OVERSHOOT_DEG = 5.0  # a bank limit's overshoot in a turn's entry [deg]
CLIMB_PARAMS = (("TECS_CLMB_MAX", "FW_T_CLMB_MAX"), ("TECS_SINK_MAX", "FW_T_SINK_MAX"))
HOLD_PARAMS = frozenset({"MPC_TILTMAX_AIR", "ANGLE_MAX", "MPC_ACC_HOR", "LOIT_BRK_ACCEL",
                         "FW_R_LIM", "ROLL_LIMIT_DEG", "NAV_LOITER_RAD", "WP_LOITER_RAD"})  # fmt: skip


def _get(params: Mapping[str, float], *names: str) -> tuple[str, float] | None:
    for n in names:
        if n in params:
            try:
                return n, float(params[n])
            except (TypeError, ValueError):
                return n, math.nan
    return None


def check_params(spec: EnvelopeSpec, params: Mapping[str, float],
                 pos_speed_max_mps: float = POS_SPEED_MAX_MPS) -> dict[str, str]:  # fmt: skip
    """{parameter name: one-line reason} for every rule the parameters break ({} = consistent)."""
    dyn, lim = spec.dynamics, spec.limits
    bad: dict[str, str] = {}

    def nonfinite(name: str, v: float) -> bool:
        if not math.isfinite(v):
            bad[name] = f"{name} = {v} is not a number"
            return True
        return False

    vmax = lim.speed_h_mps
    got = _get(params, "COM_OF_LOSS_T", "GUID_TIMEOUT")
    if got and not nonfinite(*got):
        n, t_loss = got
        run_on = (t_loss + dyn.dt_s - dyn.react_s) * vmax
        if run_on > lim.margin_m + 1e-9:  # (at t_max itself: equal, up to rounding)
            t_max = dyn.react_s - dyn.dt_s + lim.margin_m / vmax
            bad[n] = (
                f"{n} = {t_loss:g} s: on link loss the vehicle runs on {run_on:.1f} m past the "
                f"envelope's {dyn.react_s:g} s reaction at {vmax:g} m/s, more than its "
                f"{lim.margin_m:g} m margin (set {n} <= {t_max:.2f} s)"
            )
    if dyn.bank_max_rad <= 0:  # multirotor: it brakes
        got = _get(params, "MPC_TILTMAX_AIR", "ANGLE_MAX")
        if got and not nonfinite(*got):
            n, v = got
            deg = v / 100.0 if n == "ANGLE_MAX" else v
            a = GRAVITY * math.tan(math.radians(min(max(deg, 0.0), 89.0)))
            if a < dyn.decel_h_mps2:
                bad[n] = (f"{n} = {v:g}: the hold can brake at most {a:.2f} m/s², the envelope "
                          f"counts on {dyn.decel_h_mps2:g} m/s²")  # fmt: skip
        got = _get(params, "MPC_ACC_HOR", "LOIT_BRK_ACCEL")
        if got and not nonfinite(*got):
            n, v = got
            a = v / 100.0 if n == "LOIT_BRK_ACCEL" else v
            if a < dyn.decel_h_mps2:
                bad[n] = (f"{n} = {v:g}: braking {a:.2f} m/s² is below the envelope's "
                          f"{dyn.decel_h_mps2:g} m/s²")  # fmt: skip
        got = _get(params, "MPC_XY_VEL_MAX", "WPNAV_SPEED")
        if got and not nonfinite(*got):
            n, v = got
            s = v / 100.0 if n == "WPNAV_SPEED" else v
            if s > pos_speed_max_mps + 1e-6:
                bad[n] = (f"{n} = {v:g}: position setpoints would fly at up to {s:g} m/s, the "
                          f"net certifies them at {pos_speed_max_mps:g} m/s")  # fmt: skip
    else:  # fixed-wing: it loiters
        r_env = dyn.turn_radius(vmax)
        got = _get(params, "FW_R_LIM", "ROLL_LIMIT_DEG")
        if got and not nonfinite(*got):
            n, v = got
            if math.radians(v) < dyn.bank_max_rad - 1e-9:
                bad[n] = (f"{n} = {v:g} deg: below the envelope's loiter bank "
                          f"{math.degrees(dyn.bank_max_rad):.1f} deg")  # fmt: skip
            elif v > _bank_ceiling_deg(spec) + 1e-6:
                bad[n] = (f"{n} = {v:g} deg: the autopilot may bank past the envelope's attitude "
                          f"limit {math.degrees(lim.attitude_max_rad):.0f} deg "
                          f"(set {n} <= {_bank_ceiling_deg(spec):g})")  # fmt: skip
        got = _get(params, "NAV_LOITER_RAD", "WP_LOITER_RAD")
        if got and not nonfinite(*got):
            n, r = got
            if n == "NAV_LOITER_RAD" and r <= 0:
                trim = _get(params, "FW_AIRSPD_TRIM")
                rlim = _get(params, "FW_R_LIM")
                if trim and rlim and math.isfinite(trim[1]) and math.isfinite(rlim[1]):
                    r = trim[1] ** 2 / (GRAVITY * math.tan(0.7 * math.radians(rlim[1])))
            if abs(r) > r_env:
                bad[n] = (f"{n} = {got[1]:g}: the hold circle ({abs(r):.0f} m) is wider than the "
                          f"envelope's loiter reserve R = {r_env:.0f} m")  # fmt: skip
        for names, (what, limit) in zip(CLIMB_PARAMS, _climb_limits(spec)):
            got = _get(params, *names)
            if got and not nonfinite(*got):
                n, v = got
                if v > limit + 1e-6:
                    bad[n] = (f"{n} = {v:g} m/s: the autopilot may {what} faster than the "
                              f"envelope's {limit:g} m/s (set {n} <= {limit:g})")  # fmt: skip
    got = _get(params, "COM_OBL_RC_ACT")
    if got and not nonfinite(*got):
        n, v = got
        if int(v) not in PX4_OBL_OK:
            bad[n] = (f"{n} = {v:g}: offboard loss would not brake or return "
                      f"(use one of {sorted(PX4_OBL_OK.items())})")  # fmt: skip
    return bad


def _climb_limits(spec: EnvelopeSpec) -> tuple[tuple[str, float], tuple[str, float]]:
    lim = spec.limits
    return (("climb", lim.climb_mps), ("sink", lim.descent_mps))


def _bank_ceiling_deg(spec: EnvelopeSpec) -> float:
    """The highest bank limit C7 allows [whole deg]."""
    return float(math.floor(math.degrees(spec.limits.attitude_max_rad) - BANK_OVERSHOOT_DEG))


def required_values(
    spec: EnvelopeSpec, params: Mapping[str, float], pos_speed_max_mps: float = POS_SPEED_MAX_MPS
) -> dict[str, float]:
    """{name: value} that makes each parameter `check_params` faults agree with the envelope,
    in the autopilot's own unit, rounded toward the safe side (C1 link-loss time down, C2
    tilt and braking up, C3 position speed down, C4 loiter radius down and bank up to the
    loiter bank, C6 climb / sink down, C7 bank down); what `--configure-autopilot` sets.
    Left out, for the operator: a parameter that is not a number, C1 when no positive time
    fits, C4 when the bank cannot be both >= the loiter bank and <= the attitude row's less
    the overshoot, and C5 (COM_OBL_RC_ACT: an INT32 that PARAM_SET's float does not carry)."""
    dyn, lim = spec.dynamics, spec.limits
    bad = check_params(spec, params, pos_speed_max_mps)
    out: dict[str, float] = {}
    for n in bad:
        got = _get(params, n)
        if got is None or not math.isfinite(got[1]):
            continue
        if n in ("COM_OF_LOSS_T", "GUID_TIMEOUT"):  # C1
            t_max = dyn.react_s - dyn.dt_s + lim.margin_m / lim.speed_h_mps
            if t_max >= 0.01:
                out[n] = math.floor(t_max * 100.0) / 100.0
        elif n in ("MPC_TILTMAX_AIR", "ANGLE_MAX"):  # C2: the tilt that brakes at decel
            deg = math.degrees(math.atan(dyn.decel_h_mps2 / GRAVITY))
            out[n] = float(math.ceil(deg * 100.0)) if n == "ANGLE_MAX" else math.ceil(deg * 10) / 10
        elif n in ("MPC_ACC_HOR", "LOIT_BRK_ACCEL"):  # C2: braking
            a = dyn.decel_h_mps2
            out[n] = (
                float(math.ceil(a * 100.0)) if n == "LOIT_BRK_ACCEL" else math.ceil(a * 10) / 10
            )
        elif n in ("MPC_XY_VEL_MAX", "WPNAV_SPEED"):  # C3
            v = pos_speed_max_mps
            out[n] = float(math.floor(v * 100.0)) if n == "WPNAV_SPEED" else math.floor(v * 10) / 10
        elif n in ("NAV_LOITER_RAD", "WP_LOITER_RAD"):  # C4: the hold circle
            out[n] = float(math.floor(dyn.turn_radius(lim.speed_h_mps)))
        elif n in ("FW_R_LIM", "ROLL_LIMIT_DEG"):  # C4 (raise to the loiter bank) / C7 (lower)
            low, top = math.degrees(dyn.bank_max_rad), _bank_ceiling_deg(spec)
            if top >= low:
                out[n] = top if got[1] > top else float(math.ceil(low))
        elif n in ("TECS_CLMB_MAX", "FW_T_CLMB_MAX", "TECS_SINK_MAX", "FW_T_SINK_MAX"):  # C6
            climb = n in ("TECS_CLMB_MAX", "FW_T_CLMB_MAX")
            out[n] = float(lim.climb_mps if climb else lim.descent_mps)
    return out


AGREEING = ("TECS_CLMB_MAX", "FW_T_CLMB_MAX", "TECS_SINK_MAX", "FW_T_SINK_MAX", "FW_R_LIM",
            "ROLL_LIMIT_DEG")  # fmt: skip
"""What a fixed-wing mission sets by itself (C6, C7: limits lowered, never raised)."""


def agreeing_values(spec: EnvelopeSpec, params: Mapping[str, float]) -> dict[str, float]:
    """{name: value} a companion may PARAM_SET so that the autopilot agrees with the envelope
    where it can without being asked (a fixed-wing's climb and sink limits lowered to the
    envelope's, C6; a bank limit lowered to the attitude row's less the overshoot, C7); {} for
    a multirotor or when nothing needs changing. Everything else is `required_values`, set
    only when the operator asks (`--configure-autopilot`)."""
    if spec.dynamics.bank_max_rad <= 0:
        return {}
    req = required_values(spec, params)
    return {n: req[n] for n in AGREEING if n in req and req[n] <= float(params[n])}


class ParamGuard:
    """The autopilot's parameters as they arrive (PARAM_VALUE) → the supervisor's
    `Health.params_fault` and a hand-over verdict; each change of verdict is an event."""

    def __init__(self, spec: EnvelopeSpec, pos_speed_max_mps: float = POS_SPEED_MAX_MPS, events=None,
                 vehicle: str = "uav0"):  # fmt: skip
        self.spec = spec
        self.pos_speed_max = pos_speed_max_mps
        self.events = events
        self.vehicle = vehicle
        self.params: dict[str, float] = {}
        self.problems: dict[str, str] = {}
        self.safe: dict[str, float] = {}  # each parameter's last value that broke no rule
        self._restored: dict[str, float] = {}  # name → when its restore was last sent [s]

    def load(self, t: float, params: Mapping[str, float]) -> str:
        """All parameters at start; returns the fault ("" = consistent)."""
        self.params.update({k: v for k, v in params.items()})
        fault = self._recheck(t, "parameters read")
        self.safe.update({k: v for k, v in self.params.items() if k not in self.problems})
        return fault

    def update(self, t: float, name: str, value: float) -> str:
        """One PARAM_VALUE (after anyone's PARAM_SET); returns the fault ("" = consistent)."""
        name = str(name).rstrip("\x00")
        self.params[name] = value
        fault = self._recheck(t, f"{name} = {value}")
        if name not in self.problems:
            self.safe[name] = value
        return fault

    def restores(self, t: float) -> dict[str, float]:
        """{name: value} to PARAM_SET at t: each parameter breaking a rule now, back to its
        last value that broke none (none known: left to the operator), again every
        RESTORE_RETRY_S until its echo agrees; each send is an event."""
        out = {}
        for n in sorted(self.problems):
            if n in self.safe and t - self._restored.get(n, -math.inf) >= RESTORE_RETRY_S:
                self._restored[n] = t
                out[n] = self.safe[n]
        for n, v in out.items():
            self._event(t, "param_restore", {"name": n, "value": v, "reason": self.problems[n]})
        return out

    @property
    def hold_ok(self) -> bool:
        """False when the autopilot's own hold (its braking or loiter circle) disagrees with
        the envelope: the net then flies its own fallback in OFFBOARD instead of HOLD."""
        return not (set(self.problems) & HOLD_PARAMS)

    @property
    def fault(self) -> str:
        """ "" when consistent; else the reasons joined by "; " (for Health.params_fault)."""
        return "; ".join(self.problems[k] for k in sorted(self.problems))

    def handover(self) -> tuple[bool, str]:
        """May the AI be given the vehicle? (False, reason) while parameters disagree."""
        return (not self.problems, self.fault)

    def _recheck(self, t: float, what: str) -> str:
        new = check_params(self.spec, self.params, self.pos_speed_max)
        if new != self.problems:
            self._event(t, "params", {"trigger": what, "consistent": not new,
                                      "reason": "; ".join(new.values()) or
                                      "autopilot parameters agree with the envelope"})  # fmt: skip
        self.problems = new
        for n in [n for n in self._restored if n not in new]:
            del self._restored[n]  # agrees again: its restore is done
        return self.fault

    def _event(self, t: float, kind: str, fields: dict[str, Any]) -> None:
        if self.events is None:
            return
        rec: dict[str, Any] = {"t": round(float(t), 6), "event": kind, "vehicle": self.vehicle}
        try:
            self.events.write({**rec, **fields})
        except Exception:  # noqa: BLE001  logging never stops the safety net
            pass
