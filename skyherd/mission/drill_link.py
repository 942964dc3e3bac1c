"""Campaign drills flown by the companion's mission code: a drill = `skyherd fly`'s mission
(mission.flight.SingleVehicleMission: the same SafetyNet, authority, decision records) with an
adversarial pilot (mission.pilots.DrillPilot, the drill's script) and faults, flown over real
loopback MAVLink against the built-in vehicle (flight.sitl.Sitl) in lockstep on the simulation
clock, as `skyherd sim` ticks its vehicle (flight.lockstep): the vehicle marks every `TICK_S`,
the companion (mission.companion.run) decides on that tick's telemetry and closes it, and the
vehicle does not step past the mark + L before the close. A drill therefore runs as fast as the
CPU allows, and the same drill flies the same at any load.

Every campaign kind (safety.campaign), both airframes. The vehicle starts in the air at the
drill's start point (armed, HOLD; the fixed-wing trimmed in level flight over home with the
drill's fence uploaded, as safety.campaign.make_vehicle); the mission starts with
`FlightPlan.air_start`: it reads the parameters, hands over with the profile's recipe, flies the
pilot behind the net for the script's duration, then holds (no landing: a drill ends in the
air by design, or where the autopilot's failsafe flies).

The adversary (`Adversary`, the vehicle's side, on the script's clock from its first decision):
the drill's fault plan (wind, GPS glitch, battery) moved onto that clock; a PARAM_SET from
another client to the vehicle's ground-station port (any sender is obeyed: the endpoint's
PARAM_VALUE broadcast reaches the companion, whose guard reads it); a restore (value None)
sends the value read before the sabotage; a link cut of the API link both ways (nothing from
the vehicle reaches the companion; the ticks' marks still come, they are the simulation's
clock; what the companion sends is dropped).

Ground truth is recorded on every simulation step, with whose each mode change was: while the
net has authority, a change to the mode it last asked for is the net's, any other the
autopilot's own; after the yield, a change to OFFBOARD, or out of RTL / LAND into the net's
modes, can only be the net's (the one other client on the link): an override. Judged by
safety.judge as the in-process drills (safety.drills.judge_drill).
"""

from __future__ import annotations

import dataclasses
import math
import socket
import threading
from dataclasses import dataclass, field
from pathlib import Path

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.lockstep import LockstepParams
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.sitl import Sitl
from skyherd.hil.link import MavlinkLink
from skyherd.mission.companion import CompanionParams, run
from skyherd.mission.flight import FlightPlan, Record, SingleVehicleMission
from skyherd.mission.pilots import DrillPilot
from skyherd.mission.steps import MissionError
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio import ports
from skyherd.runio.constants import COMPANION_COMPONENT
from skyherd.safety.authority import ENDING_MODES, NET_MODES, Phase
from skyherd.safety.campaign import KINDS, drill_rng, make_drill, make_vehicle
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.drills import (
    RUN_ON_S,
    DrillParams,
    DrillRecord,
    judge_drill,
    own_flight_of,
    recovery_allowance_s,
)
from skyherd.safety.judge import NetRecord, first_failed, verdict
from skyherd.safety.net import SafetyNet, warm_up
from skyherd.safety.supervisor import Mode, Supervisor, SupervisorParams

M = mavlink2
MAVLINK_KINDS = KINDS  # every campaign kind flies through the mission code
AIRFRAMES = ("quadrotor", "fixedwing")
TICK_S = 0.1
"""The companion's tick [s of simulation time]: `skyherd fly`'s (one per camera frame,
world.sim.WorldParams.camera_hz = 10 Hz; tests/safety/test_drill_mission.py holds the two equal)."""
FAULT_PARK_S = 1.0e4
"""The drill's timed faults wait this far out until the script's clock starts [s]."""
INSTANCE_TRIES = 32  # vehicle instances tried from the first one asked for (a busy port: next)


@dataclass
class LinkDrillResult:
    name: str
    kind: str
    passed: bool
    min_clearance_m: float  # ground truth, while the net is answerable (see run_mission_drill)
    overridden: int
    yielded: str
    reasons: list[str]
    why: str
    setpoints: int  # decisions the mission recorded (decisions.jsonl rows)
    airframe: str = "quadrotor"
    restored: str = ""  # after a client's restore: "handed back", "waiting (yielded ...)", ...
    cut_dropped: int = 0  # datagrams from the companion dropped by the link cut
    checks: list = field(default_factory=list)  # safety.judge's, in order
    decisions: list = field(default_factory=list, repr=False)  # the mission's records
    outcome: str = ""  # the mission's: completed / yielded / aborted
    end_mode: str = ""  # the net's mode at the end: ai / fallback / pid
    sim_s: float = 0.0  # simulation time flown [s]
    track: list = field(default_factory=list, repr=False)  # (t, n, e, d) every 0.1 s, truth
    switches: int = 0  # the net's switches (supervisor stats)
    fallback_s: float = 0.0
    pid_s: float = 0.0
    autopilot_excursion_m: float = -math.inf  # worst, in the autopilot's own flight after a yield
    autopilot_excursion_mode: str = ""


class Adversary:
    """What the attacker does, on the simulation thread after every step (module docstring)."""

    def __init__(self, sitl: Sitl, script, handover_s: float):
        self.sitl, self.s, self.handover_s = sitl, script, handover_s
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.mav = M.MAVLink(None, 255, 190)  # another client: a ground station's ids
        self.pending = sorted(script.params, key=lambda e: e[0])
        self.before: dict[str, float] = {}  # each parameter's value before its sabotage
        self.cut = False
        self.dropped = 0
        self.t0: float | None = None  # the script's clock origin [s of simulation time]

    def on_step(self, t0: float | None) -> None:
        """After every step; t0: the script's clock origin as of the last closed tick."""
        if t0 is None:
            return
        ap = self.sitl.autopilot
        if self.t0 is None:  # the script starts: its faults move onto its clock
            self.t0 = t0
            inj = getattr(ap, "_inj", None)
            if inj is not None and inj.plan.events:
                inj.shift(t0 - self.handover_s - FAULT_PARK_S, ap.clock.t)
        tr = ap.clock.t - t0
        cut = self.s.link_cut
        self.cut = cut is not None and cut[0] <= tr < cut[1]
        self.sitl.endpoint.api.muted = self.cut
        while self.pending and self.pending[0][0] <= tr:
            _, name, value = self.pending.pop(0)
            self.before.setdefault(name, float(ap.get_param(name)))
            value = self.before[name] if value is None else value
            cfg = self.sitl.endpoint.config
            msg = M.MAVLink_param_set_message(cfg.system_id, 1, name.encode(), float(value),
                                              M.MAV_PARAM_TYPE_REAL32)  # fmt: skip
            self.sock.sendto(msg.pack(self.mav), cfg.gcs_bind)

    def admit(self, batch: list) -> list:
        """What of the companion's closed tick reaches the vehicle: nothing during a cut."""
        if self.cut:
            self.dropped += len(batch)
            return []
        return batch

    def close(self) -> None:
        self.sock.close()


def parked(drill):
    """The drill with its timed faults moved FAULT_PARK_S out (Adversary moves them back)."""
    f = drill.faults
    events = tuple(dataclasses.replace(e, t0=e.t0 + FAULT_PARK_S) for e in f.events)
    return dataclasses.replace(drill, faults=dataclasses.replace(f, events=events))


def open_sitl(ap, instance: int, lockstep: LockstepParams) -> tuple[Sitl, MavlinkLink, int]:
    """The vehicle's endpoint and the companion's link on the first free instance from
    `instance` (parallel drills each take one)."""
    last: OSError | None = None
    for n in range(instance, min(instance + INSTANCE_TRIES, ports.MAX_INSTANCE + 1)):
        try:
            sitl = Sitl(ap, EndpointConfig(instance=n), speedup=0.0, lockstep=lockstep,
                        tick_s=TICK_S)  # fmt: skip
        except OSError as e:
            last = e
            continue
        try:
            link = MavlinkLink.open(ports.companion_address(n), source_system=1 + n,
                                    source_component=COMPANION_COMPONENT)  # fmt: skip
        except Exception as e:  # noqa: BLE001 - the companion's port is taken: the next one
            sitl.close()
            last = e if isinstance(e, OSError) else OSError(str(e))
            continue
        return sitl, link, n
    raise OSError(f"no free vehicle instance in [{instance}, {instance + INSTANCE_TRIES}): {last}")


def run_mission_drill(kind: str, airframe: str = "quadrotor", index: int = 0, seed: int = 0,
                      instance: int = 100, events=None,
                      envelope: Path | None = None) -> LinkDrillResult:  # fmt: skip
    """One campaign drill of `kind` for `airframe`, flown by the companion's mission code
    (module docstring) on the first free vehicle instance from `instance`; `envelope`: the
    constraint set (default the airframe's field set)."""
    if kind not in MAVLINK_KINDS:
        raise ValueError(f"kind {kind!r}: choose one of {MAVLINK_KINDS}")
    if airframe not in AIRFRAMES:
        raise ValueError(f"airframe {airframe!r}: choose one of {AIRFRAMES}")
    spec, table = load_envelope(
        envelope if envelope is not None else default_envelope_path(airframe)
    )
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    d = make_drill(kind, index, drill_rng(seed, airframe, index), spec, p)
    s = d.script
    ap = make_vehicle(parked(d), seed)
    if airframe == "fixedwing":
        ap.start_in_air(-float(s.start_ned[2]), p.fixedwing_speed_mps, s.start_heading)
    else:
        ap.arm(force=True)
        ap.set_mode(FlightMode.HOLD)
    net = SafetyNet(Supervisor(d.spec.envelope(), sp, events), events, camera=False)
    warm_up(net.supervisor.envelope, sp)  # as the companion: not at the first switch in flight
    judged = s.must_recover and not s.expect_yield  # on its recovery: runs long enough for it
    pilot = DrillPilot(s, p, s.duration_s, name=f"drill:{s.name}", air_start=True,
                       recovery_s=recovery_allowance_s(d.spec, sp) if judged else 0.0,
                       net_mode=lambda: net.mode)  # fmt: skip
    plan = FlightPlan(altitude_m=-float(s.start_ned[2]), duration_s=pilot.last_call_s + TICK_S,
                      decision_s=TICK_S, land=False, yield_wait_s=s.after_yield_s,
                      air_start=True)  # fmt: skip
    record = Record()
    mission = SingleVehicleMission(pilot, net, plan, record)
    sitl, link, n = open_sitl(ap, instance, LockstepParams())
    adv = Adversary(sitl, s, s.handover_s)
    rec = DrillRecord()
    auth = net.authority
    # What the companion's side is, read only when its tick has closed (the vehicle is then
    # at the mark + L, the companion waiting for the next mark): read while the vehicle steps
    # between the mark and the close, it would depend on the threads' timing.
    now = {"handed": False, "authority": False, "asked": None, "asked_t": math.nan,
           "ai": False, "t0": None}  # fmt: skip

    def on_close(batch: list) -> list:  # the simulation thread, at each tick's close
        now.update(handed=auth.phase is not Phase.BEFORE, authority=auth.has_authority,
                   asked=auth.asked, asked_t=auth.asked_t, t0=pilot.t0,
                   ai=net.mode is Mode.AI and not net.params.fault)  # fmt: skip
        return adv.admit(batch)

    j = {"mode": ap.mode, "overridden": 0, "t_yield": math.nan, "ai_after": math.nan}
    t_restore = max((t for t, _, v in s.params if v is None), default=math.nan)
    track: list = []

    def whose(prev: FlightMode, m: FlightMode) -> bool:
        """The net's change (True) or the autopilot's own (False); module docstring."""
        if now["authority"]:
            return m is now["asked"]
        return m is FlightMode.OFFBOARD or (prev in ENDING_MODES and m in NET_MODES)

    def on_step(_sitl: Sitl) -> None:  # the simulation thread, every step
        adv.on_step(now["t0"])
        m, prev = ap.mode, j["mode"]
        j["mode"] = m
        if math.isnan(rec.t0):
            if not now["handed"]:
                return
            rec.handover(now["asked_t"], prev, ap.armed)
        by = whose(prev, m) if m is not prev else False
        if m is not prev and by and not now["authority"]:
            j["overridden"] += 1
        t = ap.clock.t
        pos = ap.true_state.pos_ned
        rec.step(t, pos, ap.armed, m, by)
        if not track or t - track[-1][0] >= 0.1 - 1e-9:
            track.append((t, *map(float, pos)))
        if not now["authority"] and math.isnan(j["t_yield"]):
            j["t_yield"] = t
        if (adv.t0 is not None and t - adv.t0 >= t_restore and math.isnan(j["ai_after"])
                and now["ai"]):  # fmt: skip
            j["ai_after"] = t - adv.t0

    failure: list[BaseException] = []

    def fly_vehicle() -> None:
        try:
            sitl.run(on_step=on_step, on_close=on_close)
        except BaseException as e:  # noqa: BLE001 - reported by the drill
            failure.append(e)

    sim = threading.Thread(target=fly_vehicle, name="drill-vehicle", daemon=True)
    outcome, why = "completed", "the drill ran to its end"
    v = VehicleLink(link, target_system=1 + n)
    try:
        sim.start()
        try:
            run(v, mission, mission.run(v), None, CompanionParams(lockstep=True))
        except MissionError as e:
            outcome, why = "aborted", f"the mission failed: {e}"
    finally:
        sitl.request_stop()
        sim.join(timeout=30.0)
        link.close()
        sitl.close()
        adv.close()
    if failure:
        outcome, why = "aborted", f"the vehicle's loop failed: {failure[0]!r}"
    if math.isnan(rec.t0):
        outcome, why = "aborted", why if outcome == "aborted" else "the net never took the vehicle"
    sup = net.supervisor
    seen = sorted({r["reason"] for r in record.rows if r["mode"] != Mode.AI.value and r["reason"]})
    reasons = sup.stats.reasons + sup.stats.projected_reasons + seen
    yielded = auth.yields[0][1] if auth.yields else ""
    ty = j["t_yield"] if yielded else math.nan
    run_on = d.spec.stop_times()[0] + RUN_ON_S
    net_rec = NetRecord(tuple(reasons), yielded, ty, ty + run_on if yielded else math.inf,
                        sup.mode.value, j["ai_after"], d.spec.limits.breach_tolerance_m)  # fmt: skip
    truth_end = rec.t[-1] if rec.t else ap.clock.t
    checks = judge_drill(s, d.spec, rec, net_rec, None, ty if yielded else truth_end, outcome, why)
    failed = first_failed(checks)
    restored = next(c for c in checks if c.name == "recovered").figure
    if auth.yields:
        reasons.append(auth.reason)
    own_x, own_mode = own_flight_of(rec, d.spec, net_rec)
    st = sup.stats
    return LinkDrillResult(s.name, kind, failed is None, checks[0].value, j["overridden"], yielded,
                           reasons, "" if failed is None else verdict(checks), len(record.rows),
                           airframe, restored if not math.isnan(t_restore) else "", adv.dropped,
                           checks, record.rows, mission.outcome, sup.mode.value,
                           ap.clock.t, track, st.switches, st.fallback_s, st.pid_s, own_x,
                           own_mode)  # fmt: skip
