"""One vehicle's mission: connect, arm, take off, hand over, fly a pilot behind the safety net,
land — as one generator (mission.steps), with what the run folder records.

The flying part is the same for every pilot: at each decision (every `decision_s`) the pilot
proposes a setpoint from the observation; at every tick the safety net certifies (it may hold a
proposal, project it, or take over with its fallback); `Authority` maps the net's mode onto the
autopilot's (AI: OFFBOARD, fallback: the autopilot's own hold) and yields when the autopilot
takes over by itself. Every decision goes to decisions.jsonl: proposed, certified, verdict,
reason, mode (LAYOUT of the per-decision record in docs/mission.md).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from flight.autopilot_api import FlightMode, Setpoint
from mission.authority import ModeAuthority
from mission.pilots import Observation, Pilot, Proposal
from mission.steps import MissionError, Phase, read_params, recipe, wait_ready, wait_until
from mission.vehicle import VehicleLink
from runio import CsvWriter, JsonlWriter
from safety.supervisor import Decision, Health, Mode, Supervisor

TRACK_COLUMNS = ["t", "north", "east", "down", "vn", "ve", "vd", "mode", "armed", "phase"]


@dataclass(frozen=True)
class FlightPlan:
    """What one vehicle does (saved in config.json)."""

    altitude_m: float = 20.0  # take-off and hand-over altitude above home [m]
    duration_s: float = 60.0  # flight behind the safety net after the hand-over [s]
    decision_s: float = 0.5  # the pilot decides this often [s] (the policy's training step)
    land: bool = True  # land at the end (else hold position and stop)
    yield_wait_s: float = 60.0  # after the autopilot took over, wait this long for its landing [s]

    def __post_init__(self) -> None:
        if not 0 < self.altitude_m <= 500:
            raise ValueError(f"altitude_m must be in (0, 500] m, got {self.altitude_m}")
        if not 0 < self.duration_s <= 36000:
            raise ValueError(f"duration_s must be in (0, 36000] s, got {self.duration_s}")
        if not self.decision_s > 0:
            raise ValueError(f"decision_s must be > 0, got {self.decision_s}")


def _vec(x) -> list[float] | None:
    return None if x is None else [round(float(a), 6) for a in x]


def _sp(s: Setpoint | None) -> dict | None:
    if s is None:
        return None
    return {"pos_ned": _vec(s.pos_ned), "vel_ned": _vec(s.vel_ned),
            "yaw": None if s.yaw is None else round(float(s.yaw), 6)}  # fmt: skip


def append_track(track: CsvWriter | None, v: VehicleLink, written: int, phase: str) -> int:
    """Append the position samples that arrived since `written` to metrics.csv (TRACK_COLUMNS);
    returns how many are written now."""
    if track is not None:
        for t, p, vel, mode, armed in v.positions[written:]:
            track.write({"t": t, "north": p[0], "east": p[1], "down": p[2], "vn": vel[0],
                         "ve": vel[1], "vd": vel[2], "mode": mode, "armed": int(armed),
                         "phase": phase})  # fmt: skip
    return len(v.positions)


def verdict(d: Decision) -> str:
    if d.mode is Mode.FALLBACK:
        return "fallback"
    if d.mode is Mode.PID:
        return "pid"
    return "projected" if d.ai_rejected else "accepted"


@dataclass
class Record:
    """What the companion writes while it flies (each writer appends and flushes)."""

    decisions: JsonlWriter | None = None
    track: CsvWriter | None = None
    vehicle: str = "uav0"
    rows: list[dict] = field(default_factory=list)  # the decisions, for the report

    live: object | None = None  # a Zenoh publisher of skyherd/<vehicle>/decision (or None)

    def decision(self, row: dict) -> None:
        self.rows.append(row)
        if self.decisions is not None:
            self.decisions.write(row)
        if self.live is not None:
            try:
                self.live.put(json.dumps(row).encode())
            except Exception:  # noqa: BLE001 - a dead session never stops the flight
                self.live = None


class SingleVehicleMission:
    """connect → arm → take off → hand over → pilot behind the net → land."""

    def __init__(self, pilot: Pilot, supervisor: Supervisor | None, plan: FlightPlan,
                 record: Record, perception=None, guard=None):  # fmt: skip
        self.pilot, self.net, self.plan, self.rec = pilot, supervisor, plan, record
        self.perception = perception  # mission.perception.Perception or None (no camera)
        self.authority = ModeAuthority(getattr(supervisor, "events", None))
        self.guard = (
            guard  # safety.consistency.ParamGuard: the autopilot's parameters vs the envelope
        )
        self.phase = "connect"
        self.outcome = "running"
        self.reason = ""
        self.t_decision: float | None = None
        self.pending: Proposal | None = None
        self._written = 0
        self.name = pilot.name

    # ---- called by the companion's loop --------------------------------------------------------
    def on_frame(self, t: float, frame, status: str) -> None:
        if self.perception is not None:
            self.perception.on_frame(t, frame, status)

    def write_track(self, v: VehicleLink) -> None:
        self._written = append_track(self.rec.track, v, self._written, self.phase)

    # ---- the mission ---------------------------------------------------------------------------
    def run(self, v: VehicleLink) -> Phase:
        plan = self.plan
        self.phase = "connect"
        yield from wait_ready(v)
        prof = v.profile
        if self.guard is not None:  # envelope ↔ autopilot: refuse to fly on a mismatch
            self.phase = "parameters"
            yield from read_params(v)
            self.guard.load(v.t, v.params)
            v.param_updates.clear()
            ok, why = self.guard.handover()
            if not ok:
                raise MissionError(
                    f"refusing to take off: the autopilot's parameters disagree with the envelope: {why}"
                )
        self.phase = "takeoff"
        yield from recipe(v, prof.takeoff_steps(plan.altitude_m, v.home_amsl_m))
        self.phase = "offboard"
        yield from recipe(v, prof.handover_steps(), hold=lambda: self._hold(v))
        self.authority.adopt(v, prof.ai_mode)
        self.phase = self.pilot.name
        t_end = v.t + plan.duration_s
        while v.t < t_end - 1e-9 and not getattr(self.pilot, "done", False):
            rule = self.authority.update(v)
            if rule == "end":
                break
            if rule == "wait":  # yielded to a non-landing mode: perceive, command nothing
                self.phase, v.setpoint = "autopilot", None
            else:
                self.phase = self.pilot.name
                self._tick(v)
            yield
        if self.authority.yielded is not None:
            yield from self._yield_to_autopilot(v)
            return
        self.phase = "land"
        if plan.land:
            v.setpoint = Setpoint(pos_ned=v.tel.pos_ned.copy(), yaw=0.0)
            yield from recipe(v, prof.land_steps())
            yield from recipe(v, prof.end_steps())
        self.outcome = "completed"

    def _hold(self, v: VehicleLink) -> Setpoint:
        p = v.tel.pos_ned
        return Setpoint(pos_ned=np.array([p[0], p[1], -self.plan.altitude_m]), yaw=0.0)

    def _yield_to_autopilot(self, v: VehicleLink) -> Phase:
        """The autopilot has the vehicle: stop streaming, ask for nothing, wait for it to land."""
        self.phase = "autopilot"
        v.setpoint = None
        self.outcome, self.reason = "yielded", self.authority.yielded
        try:  # the stated rule: wait for its landing up to yield_wait_s, then end, left to it
            yield from wait_until(v, lambda: not v.tel.armed, self.plan.yield_wait_s,
                                  "the autopilot to land and disarm")  # fmt: skip
            self.reason += "; it landed and disarmed"
        except MissionError:
            self.reason += f"; still armed in {v.tel.mode_name or v.tel.mode} after {self.plan.yield_wait_s:.0f} s: left to the autopilot"

    def _tick(self, v: VehicleLink) -> None:
        state = v.tel.vehicle_state()
        if state is None:
            return
        t = v.t
        proposal = None
        phi = self.perception.phi if self.perception is not None else None
        if self.t_decision is None or t - self.t_decision >= self.plan.decision_s - 1e-9:
            self.t_decision = t
            obs = self.perception.observation(state) if self.perception is not None else np.zeros(0)
            proposal = self.pilot.propose(Observation(t, state, phi, obs, self.plan.decision_s))
            if self.perception is not None:
                self.perception.decided()
        if self.net is None:
            if proposal is not None:
                v.setpoint = proposal.setpoint
                self._write(t, phi, proposal, proposal.setpoint, "accepted", "no safety net", "ai",
                            v.tel.mode)  # fmt: skip
            return
        camera_t = self.perception.camera_t if self.perception is not None else t
        params_fault = ""
        if self.guard is not None:  # anyone's PARAM_SET mid-flight is re-checked here
            for t_p, name, value in v.param_updates:
                self.guard.update(t_p, name, value)
            v.param_updates.clear()
            params_fault = self.guard.fault
        d = self.net.update(t, state, None if proposal is None else proposal.setpoint,
                            Health(camera_t=camera_t, link_t=v.heartbeat_t, params_fault=params_fault,
                                   wind_mps=v.wind_speed()))  # fmt: skip
        prof = v.profile
        ai_mode = prof.fallback_mode if d.autopilot_mode is FlightMode.HOLD else prof.ai_mode
        self.authority.want(v, ai_mode)
        v.setpoint = d.command
        if proposal is not None:
            self._write(t, phi, proposal, d.command, verdict(d), d.reason, d.mode.value, ai_mode)

    def _write(self, t, phi, proposal: Proposal, certified: Setpoint, verdict_: str, reason: str,
               mode: str, autopilot_mode) -> None:  # fmt: skip
        row = {"t": round(t, 6), "vehicle": self.rec.vehicle, "pilot": self.pilot.name,
               "phi": _vec(phi), "action": proposal.action,
               "proposed": _sp(proposal.setpoint), "certified": _sp(certified),
               "verdict": verdict_, "reason": reason, "mode": mode,
               "autopilot_mode": autopilot_mode.name if autopilot_mode else ""}  # fmt: skip
        if proposal.explanation is not None:
            row["explanation"] = proposal.explanation
        self.rec.decision(row)
