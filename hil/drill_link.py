"""Campaign drills through MAVLink: the built-in vehicle behind its endpoint (flight.sitl.Sitl,
real loopback UDP), the companion side on hil.client.VehicleClient with the whole safety net
(safety.net.SafetyNet: supervisor, authority, health from arrivals, parameter guard).

Kinds flown this way, both airframes (`skyherd sitl --airframe quadrotor|fixedwing`'s vehicle):
max_speed, battery, param_sabotage, link_loss (safety.campaign). The vehicle starts in the air
at the drill's start point (armed, HOLD, before the endpoint opens; the fixed-wing trimmed in
level flight over home with the drill's fence uploaded, as safety.campaign.make_vehicle); the
companion connects, reads the parameters the guard watches, hands over to OFFBOARD and flies
the scripted AI through the net from the client's receive thread; mode requests go out from
the calling thread. A parameter sabotage is a PARAM_SET sent on the same link (any sender is
obeyed: the endpoint answers with a PARAM_VALUE broadcast that the guard reads); a restore
(value None) sends the value read before the sabotage. A link cut is real: during it the
vehicle's API link sends nothing (`muted`) and is not read, and what the companion sent meanwhile
is dropped from its socket at the end of the cut; the companion hears nothing, so it commands
nothing. Ground truth is judged on every simulation step (Sitl.run's on_step) as in
safety.drills.run_drill.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2

from flight.autopilot_api import FlightMode
from flight.mavlink import EndpointConfig
from flight.sitl import Sitl
from hil.client import VehicleClient
from hil.link import MavlinkLink
from safety.campaign import drill_rng, make_drill, make_vehicle
from safety.config import default_envelope_path, fill_dataclass, load_envelope
from safety.drills import RUN_ON_S, WATCHED_PARAMS, DrillParams
from safety.net import SafetyNet
from safety.supervisor import Mode, Supervisor, SupervisorParams

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
    setpoints: int  # setpoints the client sent
    airframe: str = "quadrotor"
    restored: str = ""  # after a client's restore: "handed back", "waiting (yielded ...)", ...
    cut_dropped: int = 0  # datagrams from the companion dropped by the link cut


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
    geo = d.spec.geometry()
    run_on = d.spec.stop_times()[0] + RUN_ON_S
    judge = {"worst": -math.inf, "t_yield": math.nan, "overridden": 0, "mode": ap.mode}
    cut = {"t0": math.nan, "on": False, "dropped": 0}  # t0: sim time of the hand-over

    def on_step(sitl: Sitl) -> None:  # simulation thread, every step
        if s.link_cut is not None and not math.isnan(cut["t0"]):
            tr = ap.clock.t - cut["t0"]
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
        z = np.zeros(11)
        z[0:3] = ap.true_state.pos_ned
        ty = judge["t_yield"]
        if math.isnan(ty) or ap.clock.t - ty <= run_on:
            judge["worst"] = max(judge["worst"], geo.worst(z))
        m = ap.mode
        if m is not judge["mode"]:
            prev, judge["mode"] = judge["mode"], m
            if prev in (FlightMode.RTL, FlightMode.LAND) or (
                not math.isnan(ty) and m is FlightMode.OFFBOARD
            ):
                judge["overridden"] += 1

    sitl = Sitl(ap, EndpointConfig(instance=instance), speedup=speedup)
    client = None
    try:
        sim = threading.Thread(target=sitl.run, kwargs={"duration_s": s.duration_s + 30.0,
                               "on_step": on_step}, name="drill-sitl", daemon=True)  # fmt: skip
        link = MavlinkLink.open(f"udpin:127.0.0.1:{14540 + instance}")
        client = VehicleClient(link, target_system=1 + instance).start()
        sim.start()
        client.wait_ready(timeout=60.0)
        net = SafetyNet(Supervisor(d.spec.envelope(), sp, events), events, camera=False)
        tel = client.telemetry
        net.params.load(tel.t, {n: client.read_param(n) for n in WATCHED_PARAMS
                                if n in ap.param_names()})  # fmt: skip
        shared: dict = {"ask": None, "t0": None, "sent": 0, "reasons": set()}

        def setpoint(tel):  # receive thread, every LOCAL_POSITION_NED
            vs = tel.vehicle_state()
            if vs is None:
                return None
            t = tel.t
            net.message(t, "HEARTBEAT")
            net.message(t, "LOCAL_POSITION_NED")
            pv = client.latest("PARAM_VALUE")
            if pv is not None:
                name = pv.param_id.rstrip("\x00")
                if name in net.params.params and net.params.params[name] != pv.param_value:
                    net.param(t, name, float(pv.param_value))
            if shared["t0"] is None:
                return vs.pos_ned, None, None  # the stream PX4 wants before OFFBOARD
            tr = t - shared["t0"]
            act = s.attack if s.t_on <= tr < s.t_off else s.behave
            dec = net.step(t, vs, act(tr, vs), tel.mode)
            ask = net.request(dec)
            shared["ask"] = ask
            if dec.mode is not Mode.AI and dec.reason:
                shared["reasons"].add(dec.reason)
            if not net.authority.has_authority:
                return None
            shared["sent"] += 1
            c = dec.command
            return c.pos_ned, c.vel_ned, c.yaw

        client.stream_offboard(setpoint)
        client.wait_message("LOCAL_POSITION_NED")
        client.wait_message("LOCAL_POSITION_NED")
        client.set_mode(FlightMode.OFFBOARD)
        net.handover(tel.t, tel.mode)  # what the heartbeat shows now (may lag the switch)
        shared["t0"] = tel.t
        cut["t0"] = shared["t0"]  # telemetry time is simulation time (time_boot_ms)
        pending = sorted(s.params, key=lambda e: e[0])
        pre_set: dict[str, float] = {}
        t_restore = max((t for t, _, v in s.params if v is None), default=math.nan)
        ai_after = math.nan
        wall_end = time.monotonic() + timeout_s
        while sim.is_alive() and time.monotonic() < wall_end:
            tr = tel.t - shared["t0"]
            if tr >= s.duration_s:
                break
            if (
                tr >= t_restore
                and math.isnan(ai_after)
                and net.supervisor.mode is Mode.AI
                and not net.params.fault
            ):
                ai_after = tr
            while pending and pending[0][0] <= tr:  # a client's PARAM_SET on the link
                _, name, value = pending.pop(0)
                pre_set.setdefault(name, float(net.params.params.get(name, math.nan)))
                value = pre_set[name] if value is None else value
                client.link.send(mavlink2.MAVLink_param_set_message(
                    1 + instance, 1, name.encode(), float(value), mavlink2.MAV_PARAM_TYPE_REAL32))  # fmt: skip
            ask = shared["ask"]
            if ask is not None and net.authority.has_authority:
                shared["ask"] = None
                net.requested(tel.t, ask, True)  # before: the heartbeat may show it first
                try:
                    client.set_mode(ask)
                except Exception:  # noqa: BLE001  denied, timed out or yielded: not asked
                    net.requested(tel.t, ask, False)
            if not math.isnan(judge["t_yield"]) and ap.clock.t - judge["t_yield"] > s.after_yield_s:
                break
            if not net.authority.has_authority and math.isnan(judge["t_yield"]):
                judge["t_yield"] = ap.clock.t
            time.sleep(0.01)
        sup = net.supervisor
        reasons = sup.stats.reasons + sorted(shared["reasons"])
        yielded = net.authority.yields[0][1] if net.authority.yields else ""
        why = []
        if judge["worst"] > d.spec.limits.breach_tolerance_m:
            why.append(f"breach {judge['worst']:.2f} m beyond the fence")
        if judge["overridden"]:
            why.append(f"the net overrode the autopilot's own mode {judge['overridden']} times")
        if (
            s.must_trigger
            and not any(k in r for r in reasons for k in s.expect)
            and not (s.expect_yield and yielded)
        ):
            why.append(f"expected {s.expect}, got {reasons or 'none'}")
        if s.expect_yield and not yielded:
            why.append("the autopilot's failsafe was expected to take over; the net never yielded")
        restored = ""
        if not math.isnan(t_restore):
            if yielded:
                restored = f"waiting (yielded to {yielded})"
            elif not math.isnan(ai_after):
                restored = f"handed back {ai_after - t_restore:.1f} s after the restore"
            else:
                restored = "not handed back"
                why.append("a client restored the sabotaged parameter; the net did not hand back")
        if net.authority.yields:
            reasons.append(net.authority.reason)
        if tel.yielded:
            reasons.append(f"client: {tel.yielded}")
        return LinkDrillResult(s.name, kind, not why, -judge["worst"], judge["overridden"],
                               yielded, reasons, "; ".join(why), shared["sent"], airframe,
                               restored, cut["dropped"])  # fmt: skip
    finally:
        if client is not None:
            client.stream_offboard(None)
            client.close()
        sitl.close()
