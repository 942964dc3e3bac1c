"""Campaign drills through MAVLink, flown by the companion's own code: the built-in vehicle
behind its endpoint (flight.sitl.Sitl, real loopback UDP), and on the other side of the link
what `skyherd companion --free-run` runs — a VehicleLink ticked by mission.companion.run on the
autopilot's clock, the phases of mission.steps (ready, parameters, the profile's hand-over
recipe), DO_SET_MODE with the profile's numbers — with the whole safety net
(safety.net.SafetyNet: supervisor, authority, health from arrivals, parameter guard).

Kinds flown this way, both airframes (`skyherd sitl --airframe quadrotor|fixedwing`'s vehicle):
max_speed, battery, param_sabotage, link_loss (safety.campaign). The vehicle starts in the air
at the drill's start point (armed, HOLD, before the endpoint opens; the fixed-wing trimmed in
level flight over home with the drill's fence uploaded, as safety.campaign.make_vehicle); the
companion connects, reads the parameters, hands over and flies the scripted AI through the net,
one decision per tick. A parameter sabotage is a PARAM_SET sent on the same link (any sender is
obeyed: the endpoint answers with a PARAM_VALUE broadcast that the guard reads); a restore
(value None) sends the value read before the sabotage. A link cut is real: during it the
vehicle's API link sends nothing (`muted`) and is not read, and what the companion sent meanwhile
is dropped from its socket at the end of the cut; the companion hears nothing, so its clock (the
autopilot's) stands still and it commands nothing. Ground truth is recorded on every
simulation step (Sitl.run's on_step) and the drill is judged by safety.judge, as the in-process
drills (safety.drills.judge_drill): the same checks, names and verdict.

Whose mode change it was, as the vehicle sees it: while the net has authority, a change to the
mode it last asked for (it marks a request asked before sending it) is the net's, any other the
autopilot's own; after the yield, a change to OFFBOARD, or out of RTL / LAND into the net's
modes, can only be the net's (the one other client on the link): an override.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, field

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.sitl import Sitl
from skyherd.hil.link import MavlinkLink
from skyherd.mission.companion import CompanionParams, run
from skyherd.mission.steps import Phase, mode_params, read_params, recipe, wait_ready
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio import ports
from skyherd.runio.constants import COMPANION_COMPONENT
from skyherd.safety.authority import ENDING_MODES, NET_MODES
from skyherd.safety.campaign import drill_rng, make_drill, make_vehicle
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.drills import RUN_ON_S, WATCHED_PARAMS, DrillParams, DrillRecord, judge_drill
from skyherd.safety.judge import NetRecord, first_failed, verdict
from skyherd.safety.net import SafetyNet, warm_up
from skyherd.safety.supervisor import Mode, Supervisor, SupervisorParams

M = mavlink2
MAVLINK_KINDS = ("max_speed", "battery", "param_sabotage", "link_loss")
AIRFRAMES = ("quadrotor", "fixedwing")


@dataclass
class LinkDrillResult:
    name: str
    kind: str
    passed: bool
    min_clearance_m: float  # ground truth, while the net is answerable (see run_drill)
    overridden: int
    yielded: str
    reasons: list[str]
    why: str
    setpoints: int  # ticks on which the companion streamed the net's command
    airframe: str = "quadrotor"
    restored: str = ""  # after a client's restore: "handed back", "waiting (yielded ...)", ...
    cut_dropped: int = 0  # datagrams from the companion dropped by the link cut
    checks: list = field(default_factory=list)  # safety.judge's, in order


class LinkDrill:
    """The companion's side of one drill, as a mission generator (mission.steps)."""

    name = "drill"

    def __init__(self, drill, net: SafetyNet, judge: dict, clock, timeout_s: float):
        self.d, self.s, self.net = drill, drill.script, net
        self.judge, self.clock = judge, clock  # the vehicle's truth: read for the stop only
        self.p = DrillParams()
        self.wall_end = time.monotonic() + timeout_s
        self.phase = "connect"
        self.t0: float | None = None  # hand-over [s of the autopilot's clock]
        self.sent = 0
        self.reasons: set[str] = set()
        self.pending: FlightMode | None = None  # a mode request not yet acknowledged
        self.t_restore = max((t for t, _, v in self.s.params if v is None), default=math.nan)
        self.ai_after = math.nan  # the net back in AI after the restore [s after hand-over]

    def on_frame(self, t: float, frame, status: str) -> None:
        pass  # no camera: the drill's net runs with camera=False

    def run(self, v: VehicleLink) -> Phase:
        net, s = self.net, self.s
        yield from wait_ready(v)
        self.phase = "parameters"
        yield from read_params(v)
        net.load_params(v.t, {n: v.params[n] for n in WATCHED_PARAMS if n in v.params})
        v.param_updates.clear()
        self.phase = "offboard"
        yield from recipe(v, v.profile.handover_steps(),
                          hold=lambda: Setpoint(pos_ned=v.tel.pos_ned.copy()))  # fmt: skip
        net.handover(v.t, v.tel.mode)  # what the heartbeat shows now (may lag the switch)
        self.t0 = v.t
        self.judge["t_handover"] = v.t  # telemetry time is simulation time (time_boot_ms)
        self.phase = "drill"
        pending = sorted(s.params, key=lambda e: e[0])
        pre_set: dict[str, float] = {}
        t_heard = v.telemetry_t
        while time.monotonic() < self.wall_end:
            t, tr = v.t, v.t - self.t0
            if tr >= s.duration_s:
                return
            if v.telemetry_t != t_heard:  # the link's health: what arrived since the last tick
                t_heard = v.telemetry_t
                net.link(t, t)
            for _, name, value in v.param_updates:  # anyone's PARAM_SET, as its echo shows
                if name in net.params.params and net.params.params[name] != value:
                    net.param(t, name, value)
            v.param_updates.clear()
            self._answered(v)
            self._decide(v, t, tr)
            while pending and pending[0][0] <= tr:  # a client's PARAM_SET on the link
                _, name, value = pending.pop(0)
                pre_set.setdefault(name, float(net.params.params.get(name, math.nan)))
                value = pre_set[name] if value is None else value
                v.send(M.MAVLink_param_set_message(v.target_system, 1, name.encode(), float(value),
                                                   M.MAV_PARAM_TYPE_REAL32))  # fmt: skip
            j = self.judge
            if not net.authority.has_authority and math.isnan(j["t_yield"]):
                j["t_yield"] = self.clock.t
            if not math.isnan(j["t_yield"]) and self.clock.t - j["t_yield"] > s.after_yield_s:
                return
            yield

    def _answered(self, v: VehicleLink) -> None:
        """The autopilot's answer to the pending mode request: a refusal withdraws it."""
        if self.pending is None:
            return
        result = v.acks.get(M.MAV_CMD_DO_SET_MODE, M.MAV_RESULT_IN_PROGRESS)
        if result != M.MAV_RESULT_IN_PROGRESS:
            v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
            if result != M.MAV_RESULT_ACCEPTED:
                self.net.requested(v.t, self.pending, False)
            self.pending = None

    def _decide(self, v: VehicleLink, t: float, tr: float) -> None:
        """One decision of the scripted AI through the net; its command streamed, its mode
        asked for, while the net has authority."""
        net, s = self.net, self.s
        vs = v.tel.vehicle_state()
        if vs is None:
            return
        if (
            tr >= self.t_restore
            and math.isnan(self.ai_after)
            and net.supervisor.mode is Mode.AI
            and not net.params.fault
        ):
            self.ai_after = tr
        dec = net.step(t, vs, s.act(tr, vs, self.p), v.tel.mode)
        ask = net.request(dec)
        if dec.mode is not Mode.AI and dec.reason:
            self.reasons.add(dec.reason)
        if not net.authority.has_authority:
            v.setpoint = None
            return
        v.setpoint = dec.command
        self.sent += 1
        if ask is not None:
            net.requested(t, ask, True)  # before: the heartbeat may show it first
            v.acks.pop(M.MAV_CMD_DO_SET_MODE, None)
            v.command_long(M.MAV_CMD_DO_SET_MODE, mode_params(v, ask), 0)
            self.pending = ask


def run_mavlink_drill(kind: str, instance: int, seed: int = 0, index: int = 0,
                      speedup: float = 1.0, events=None, timeout_s: float = 300.0,
                      airframe: str = "quadrotor") -> LinkDrillResult:  # fmt: skip
    """One campaign drill of `kind` for `airframe` through MAVLink on vehicle `instance`."""
    if kind not in MAVLINK_KINDS:
        raise ValueError(f"kind {kind!r} is not flown over MAVLink; choose one of {MAVLINK_KINDS}")
    if airframe not in AIRFRAMES:
        raise ValueError(f"airframe {airframe!r}: choose one of {AIRFRAMES}")
    spec, table = load_envelope(default_envelope_path(airframe))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    d = make_drill(kind, index, drill_rng(seed, airframe, index), spec, p)
    s = d.script
    ap = make_vehicle(d, seed)
    if airframe == "fixedwing":
        ap.start_in_air(-float(s.start_ned[2]), p.fixedwing_speed_mps, s.start_heading)
    else:
        ap.arm(force=True)
        ap.set_mode(FlightMode.HOLD)
    run_on = d.spec.stop_times()[0] + RUN_ON_S
    judge = {"t_yield": math.nan, "overridden": 0, "mode": ap.mode, "t_handover": math.nan}
    cut = {"on": False, "dropped": 0}
    rec = DrillRecord()
    box: dict = {}  # the net, once built

    def whose(prev: FlightMode, m: FlightMode) -> bool:
        """The net's change (True) or the autopilot's own (False); module docstring."""
        auth = box["net"].authority
        if auth.has_authority:
            return m is auth.asked
        return m is FlightMode.OFFBOARD or (prev in ENDING_MODES and m in NET_MODES)

    def on_step(sitl: Sitl) -> None:  # simulation thread, every step
        t0 = judge["t_handover"]
        if s.link_cut is not None and not math.isnan(t0):
            tr = ap.clock.t - t0
            on = s.link_cut[0] <= tr < s.link_cut[1]
            api = sitl.endpoint.api
            if on and not cut["on"]:
                api.muted = True  # nothing from the vehicle reaches the companion ...
                sitl.endpoint.gated.add(api.name)  # ... and nothing is read from it
            elif not on and cut["on"]:
                cut["dropped"] += len(api.receive(1 << 16))  # sent during the cut: lost
                sitl.endpoint.gated.discard(api.name)
                api.muted = False
            cut["on"] = on
        m, prev = ap.mode, judge["mode"]
        judge["mode"] = m
        if math.isnan(t0):
            return
        if math.isnan(rec.t0):
            rec.handover(t0, prev, ap.armed)
        by = whose(prev, m) if m is not prev else False
        if m is not prev and by and not box["net"].authority.has_authority:
            judge["overridden"] += 1
        rec.step(ap.clock.t, ap.true_state.pos_ned, ap.armed, m, by)

    sitl = Sitl(ap, EndpointConfig(instance=instance), speedup=speedup)
    link = None
    try:
        sim = threading.Thread(target=sitl.run, kwargs={"duration_s": s.duration_s + 30.0,
                               "on_step": on_step}, name="drill-sitl", daemon=True)  # fmt: skip
        link = MavlinkLink.open(ports.companion_address(instance), source_system=1 + instance,
                                source_component=COMPANION_COMPONENT)  # fmt: skip
        v = VehicleLink(link, target_system=1 + instance)
        net = box["net"] = SafetyNet(Supervisor(d.spec.envelope(), sp, events), events,
                                     camera=False)  # fmt: skip
        warm_up(net.supervisor.envelope, sp)  # as the companion: not at the first switch in flight
        drill = LinkDrill(d, net, judge, ap.clock, timeout_s)
        sim.start()
        run(v, drill, drill.run(v), None, CompanionParams(lockstep=False))
        sup = net.supervisor
        reasons = sup.stats.reasons + sup.stats.projected_reasons + sorted(drill.reasons)
        yielded = net.authority.yields[0][1] if net.authority.yields else ""
        ty = judge["t_yield"]
        record = NetRecord(tuple(reasons), yielded, ty, ty + run_on if yielded else math.inf,
                           sup.mode.value, drill.ai_after, d.spec.limits.breach_tolerance_m)  # fmt: skip
        outcome, why = "completed", "the drill ran to its end"
        if drill.t0 is None or time.monotonic() >= drill.wall_end:
            outcome = "aborted"
            why = f"the drill did not run to its end within {timeout_s:.0f} s of wall time"
        truth_end = rec.t[-1] if rec.t else ap.clock.t
        checks = judge_drill(s, d.spec, rec, record, None, ty if yielded else truth_end,
                             outcome, why)  # fmt: skip
        failed = first_failed(checks)
        fence = checks[0]
        restored = next(c for c in checks if c.name == "recovered").figure
        if net.authority.yields:
            reasons.append(net.authority.reason)
        return LinkDrillResult(s.name, kind, failed is None, fence.value, judge["overridden"],
                               yielded, reasons, "" if failed is None else verdict(checks),
                               drill.sent, airframe,
                               restored if not math.isnan(drill.t_restore) else "",
                               cut["dropped"], checks)  # fmt: skip
    finally:
        if link is not None:
            link.close()
        sitl.close()
