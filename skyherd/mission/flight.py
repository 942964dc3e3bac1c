"""One vehicle's mission: connect, arm, take off, hand over, fly a pilot behind the safety net,
land — as one generator (mission.steps), with what the run folder records.

The flying part is the same for every pilot: at each decision (every `decision_s`) the pilot
proposes a setpoint from the observation; at every tick the safety net (safety.net.SafetyNet)
certifies it (it may hold a proposal, project it, or take over with its fallback) and names the
autopilot mode to fly it in (AI: OFFBOARD, fallback: the autopilot's own hold), which
`ModeAuthority` requests over MAVLink; the net yields when the autopilot takes over by itself.
Every decision goes to decisions.jsonl as `Decision.record()`: proposed, certified, verdict,
reason, mode.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.mission.authority import ModeAuthority
from skyherd.mission.configure import Change, configure
from skyherd.mission.pilots import DescentPilot, Observation, Pilot, Proposal
from skyherd.mission.steps import (
    MissionError,
    Phase,
    read_params,
    recipe,
    report_modes,
    wait_ready,
    wait_until,
)
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio import CsvWriter, JsonlWriter
from skyherd.runio.mac import sign_record
from skyherd.safety.authority import Authority
from skyherd.safety.net import SafetyNet
from skyherd.safety.supervisor import Decision, Mode, Severity
from skyherd.task.params import TaskParams

TRACK_COLUMNS = ["t", "north", "east", "down", "vn", "ve", "vd", "mode", "armed", "phase"]


@dataclass(frozen=True)
class FlightPlan:
    """What one vehicle does (saved in config.json)."""

    altitude_m: float = 20.0  # take-off and hand-over altitude above home [m]
    duration_s: float = 60.0  # flight behind the safety net after the hand-over [s]
    decision_s: float = TaskParams.dt_s  # the pilot decides this often [s] (the policy's step)
    land: bool = True  # land at the end (else hold position and stop)
    descend_above_floor_m: float = 1.0  # the descent behind the net ends this far above the
    # envelope's floor + margin; the autopilot's LAND flies the column below it [m]
    descend_timeout_s: float = 60.0  # the descent behind the net must end within this [s]
    descend_held_s: float = 10.0  # the net holding (fallback / PID) this long during the
    # descent: the autopilot lands from the net's hold instead [s]
    yield_wait_s: float = 60.0  # after the autopilot took over, wait this long for its landing [s]
    air_start: bool = False  # the vehicle is already armed in the air (a drill's start point):
    # no take-off; the hand-over holds where it is (the drills through the mission code)

    def __post_init__(self) -> None:
        if not 0 < self.altitude_m <= 500:
            raise ValueError(f"altitude_m must be in (0, 500] m, got {self.altitude_m}")
        if not 0 < self.duration_s <= 36000:
            raise ValueError(f"duration_s must be in (0, 36000] s, got {self.duration_s}")
        if not self.decision_s > 0:
            raise ValueError(f"decision_s must be > 0, got {self.decision_s}")


def append_track(track: CsvWriter | None, v: VehicleLink, written: int, phase: str) -> int:
    """Append the position samples that arrived since `written` to metrics.csv (TRACK_COLUMNS);
    returns how many are written now."""
    if track is not None:
        for t, p, vel, mode, armed in v.positions[written:]:
            track.write({"t": t, "north": p[0], "east": p[1], "down": p[2], "vn": vel[0],
                         "ve": vel[1], "vd": vel[2], "mode": mode, "armed": int(armed),
                         "phase": phase})  # fmt: skip
    return len(v.positions)


@dataclass
class Record:
    """What the companion writes while it flies (each writer appends and flushes)."""

    decisions: JsonlWriter | None = None
    track: CsvWriter | None = None
    vehicle: str = "uav0"
    rows: list[dict] = field(default_factory=list)  # the decisions, for the report

    live: object | None = None  # a Zenoh publisher of skyherd/<vehicle>/decision (or None)
    live_key: bytes | None = None  # the flight's key: each live decision carries "mac" (runio.mac)

    def decision(self, row: dict) -> None:
        self.rows.append(row)
        if self.decisions is not None:
            self.decisions.write(row)
        if self.live is not None:
            try:
                self.live.put(sign_record(row, self.live_key))
            except Exception:  # noqa: BLE001 - a dead session never stops the flight
                self.live = None


class SingleVehicleMission:
    """connect → arm → take off → hand over → pilot behind the net → land."""

    def __init__(self, pilot: Pilot, net: SafetyNet | None, plan: FlightPlan, record: Record,
                 perception=None, configure_autopilot: bool = False, say=None):  # fmt: skip
        self.pilot, self.net, self.plan, self.rec = pilot, net, plan, record
        self.configure_autopilot = (
            configure_autopilot  # set what the envelope requires (mission.configure)
        )
        self.configured: list[Change] = []  # ... and what it set
        self.say = say  # a line for the operator (stderr), or None
        self.perception = perception  # mission.perception.Perception or None (no camera)
        self.authority = ModeAuthority(net.authority if net is not None else Authority())
        self.phase = "connect"
        self.outcome = "running"
        self.reason = ""
        self.t_decision: float | None = None
        self.landing_note = ""  # how the landing went, when not as planned
        self.end_mode = ""  # the profile's documented end when it does not land ("" = landed)
        self.pending: Proposal | None = None
        self._written = 0
        self.name = pilot.name

    # ---- called by the companion's loop --------------------------------------------------------
    def on_frame(self, t: float, frame, status: str) -> None:
        if self.perception is not None:
            self.perception.on_frame(t, frame, status, self.phase)
        if frame is not None and self.net is not None:
            self.net.frame(t)  # arrival = capture: the tick's own frame, or the newest

    def write_track(self, v: VehicleLink) -> None:
        self._written = append_track(self.rec.track, v, self._written, self.phase)

    # ---- the mission ---------------------------------------------------------------------------
    def run(self, v: VehicleLink) -> Phase:
        plan = self.plan
        self.phase = "connect"
        yield from wait_ready(v)
        report_modes(v)  # every mode change seen within a tick (hil.autopilots.MODE_REPORT_HZ)
        prof = v.profile
        if self.net is not None:  # envelope ↔ autopilot: refuse to fly on a mismatch
            self.phase = "parameters"
            yield from read_params(v)
            self.net.load_params(v.t, v.params)
            v.param_updates.clear()
            if self.configure_autopilot and not self.net.handover_ok()[0]:
                self.phase = "configure"
                yield from configure(v, self.net, self.configured, self.say)
                self.net.load_params(v.t, v.params)
                v.param_updates.clear()
            ok, why = self.net.handover_ok()
            if not ok:
                hint = (
                    ""
                    if self.configure_autopilot
                    else " (or let the companion set them: --configure-autopilot)"
                )
                raise MissionError(
                    f"refusing to take off: the autopilot's parameters disagree with the envelope: {why}{hint}"
                )
        if plan.air_start:  # in the air already: the hand-over holds where the vehicle is
            if not v.tel.armed:
                raise MissionError("air start: the vehicle is not armed in the air")
            hold = lambda: Setpoint(pos_ned=v.tel.pos_ned.copy(), yaw=0.0)  # noqa: E731
        else:
            if self.net is not None:  # the take-off column, certified before the take-off
                ok, why = self.net.certify_column(v.tel.pos_ned, plan.altitude_m)
                if not ok:
                    raise MissionError(f"refusing to take off: {why}")
            self.phase = "takeoff"
            yield from recipe(v, prof.takeoff_steps(plan.altitude_m, v.home_amsl_m))
            hold = lambda: self._hold(v)  # noqa: E731
        self.phase = "offboard"
        yield from recipe(v, prof.handover_steps(), hold=hold)
        if self.net is not None:
            self.net.handover(v.t, v.tel.mode, prof.ai_mode)
        else:
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
        if plan.land and self.net is not None and prof.vehicle == "multirotor":
            yield from self._descend(v)
            if self.authority.yielded is not None:
                yield from self._yield_to_autopilot(v)
                return
        self.phase = "land"
        if plan.land:
            v.setpoint = Setpoint(pos_ned=v.tel.pos_ned.copy(), yaw=0.0)
            yield from recipe(v, prof.land_steps())
            yield from recipe(v, prof.end_steps())
            self.end_mode = prof.end_mode.name if prof.end_mode else ""
        self.outcome = "completed"

    def _descend(self, v: VehicleLink) -> Phase:
        """The landing behind the net: from the mission's altitude down to the envelope's floor
        + margin (+ descend_above_floor_m), certified tick by tick like the pilot's flight (a
        wind that pushes the vehicle toward the fence meets the same rows and fallback); the
        autopilot's LAND then flies only the column below. Ends early on a yield."""
        lim = self.net.spec.limits
        goal = -(lim.floor_m + lim.margin_m + self.plan.descend_above_floor_m)
        p = v.tel.pos_ned
        if -p[2] <= -goal + 0.5:
            return  # at or below the band already: the autopilot's LAND from here
        spec = self.net.spec
        pilot = DescentPilot(float(p[0]), float(p[1]), goal, spec.limits, spec.dynamics.tau_s)
        self.phase = pilot.name
        t0, held = v.t, None
        while True:
            if self.authority.update(v) != "fly":
                return
            self._tick(v, pilot)
            p, vel = v.tel.pos_ned, v.tel.vel_ned
            if (abs(p[2] - goal) < 0.5 and float(np.linalg.norm(vel)) < 0.5
                    and self.net.mode is Mode.AI):  # fmt: skip
                return
            held = None if self.net.mode is Mode.AI else (v.t if held is None else held)
            if held is not None and v.t - held >= self.plan.descend_held_s - 1e-9:
                self.landing_note = (f"the net held the vehicle ({self.net.mode.value}: "
                                     f"{self.net.supervisor.stats.reasons[-1:] or ['?']}) for "
                                     f"{self.plan.descend_held_s:.0f} s of the descent: the "
                                     f"autopilot lands from the net's hold at {-p[2]:.1f} m")  # fmt: skip
                return
            if v.t - t0 > self.plan.descend_timeout_s:
                raise MissionError(f"the descent behind the net did not reach {-goal:.1f} m in "
                                   f"{self.plan.descend_timeout_s:.0f} s ({self.net.mode.value})")  # fmt: skip
            yield

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

    def _tick(self, v: VehicleLink, pilot: Pilot | None = None) -> None:
        state = v.tel.vehicle_state()
        if state is None:
            return
        pilot = self.pilot if pilot is None else pilot
        t = v.t
        proposal = None
        phi = self.perception.phi if self.perception is not None else None
        if self.t_decision is None or t - self.t_decision >= self.plan.decision_s - 1e-9:
            self.t_decision = t
            obs = self.perception.observation(state) if self.perception is not None else np.zeros(0)
            proposal = pilot.propose(Observation(t, state, phi, obs, self.plan.decision_s))
            if self.perception is not None:
                self.perception.decided()
        sp = None if proposal is None else proposal.setpoint
        net = self.net
        if net is None:
            if proposal is not None:
                v.setpoint = sp
                d = Decision(sp, Mode.AI, Severity.NONE, "no safety net", FlightMode.OFFBOARD,
                             False, t, sp)  # fmt: skip
                self._write(d, phi, proposal, v.tel.mode, pilot)
            return
        v.feed(net)  # link freshness, anyone's PARAM_SET, the wind estimate
        d = net.step(t, state, sp)
        want = net.wanted_mode(d)
        self.authority.want(v, want)
        v.setpoint = d.command
        if proposal is not None:
            self._write(d, phi, proposal, want, pilot)

    def _write(self, d: Decision, phi, proposal: Proposal, autopilot_mode, pilot: Pilot) -> None:
        self.rec.decision(d.record(self.rec.vehicle, pilot.name, phi, autopilot_mode or "",
                                   proposal.explanation, proposal.action))  # fmt: skip
