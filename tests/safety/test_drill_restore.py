"""Parameter sabotage and its restore (safety.drills.run_drill, safety.campaign).

A client sets COM_OF_LOSS_T or MPC_XY_VEL_MAX mid-push; the net falls back with the reason
(safety.consistency) and sets the parameter back to its last safe value at once
(ParamGuard.restores), so that the autopilot's own failsafe — here the offboard-loss HOLD of the
link cut that follows — flies safe parameters (docs/safety.md, Run 7 and Run 8)."""

from __future__ import annotations

import dataclasses

import numpy as np

from skyherd.flight.state import VehicleState
from skyherd.safety.campaign import drill_rng, make_drill, make_vehicle
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.consistency import RESTORE_RETRY_S
from skyherd.safety.drills import DrillParams, run_drill
from skyherd.safety.supervisor import Supervisor, SupervisorParams


def _quad(index: int, seed: int = 52):
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    d = make_drill("param_sabotage", index, drill_rng(seed, "quadrotor", index), spec, p)
    return d, sp, p


class Sink:
    def __init__(self):
        self.events = []

    def write(self, rec):
        self.events.append(rec)


def _fly(script, d, sp, p):
    ap = make_vehicle(d, 52)
    good = ap.get_param(script.params[0][1])
    sink = Sink()
    return ap, good, run_drill(script, ap, d.spec, sp, p, sink), sink.events


def test_the_net_sets_a_sabotaged_parameter_back_before_the_cut():
    """Drill 0015 (seed 52): COM_OF_LOSS_T = 4.5 s, then a link cut. The net sets it back to
    0.5 s on the tick its PARAM_VALUE arrives: the cut then meets the autopilot's offboard-loss
    HOLD after 0.5 s, not a 4.5 s run-on; the net yields to it."""
    d, sp, p = _quad(15)
    (t_s, name, bad), (t_r, name_r, value) = d.script.params
    assert name == name_r == "COM_OF_LOSS_T" and value is None and t_r > d.script.link_cut[1]
    ap, good, r, events = _fly(d.script, d, sp, p)
    assert bad > good
    assert r.passed, r.why
    assert any("autopilot parameters: COM_OF_LOSS_T" in x for x in r.reasons)
    t_sab, t_cut = d.script.handover_s + t_s, d.script.handover_s + d.script.link_cut[0]
    restores = [e for e in events if e["event"] == "param_restore"]
    assert restores and restores[0]["name"] == name and restores[0]["value"] == good
    assert t_sab <= restores[0]["t"] <= t_sab + 0.2 < t_cut  # the tick it arrived
    agree = [e for e in events if e["event"] == "params" and e["consistent"]]
    assert agree and agree[0]["t"] <= t_sab + 0.2  # the echo: consistent again
    assert len(restores) == 1  # echoed: never sent again
    assert r.restored == "waiting (yielded to HOLD)"  # the cut's HOLD, on safe parameters
    assert ap.get_param(name) == good


def test_without_the_clients_restore_the_net_sets_it_back_and_hands_back():
    d, sp, p = _quad(15)
    (t_s, name, bad), _ = d.script.params
    script = dataclasses.replace(d.script, params=((t_s, name, bad),), link_cut=None,
                                 must_recover=False)  # fmt: skip
    ap, good, r, events = _fly(script, d, sp, p)
    assert r.passed, r.why
    assert ap.get_param(name) == good  # the companion set it back
    switches = [e for e in events if e["event"] == "switch"]
    assert switches and switches[0]["reason"].startswith("autopilot parameters")
    t_sab = d.script.handover_s + t_s
    assert [e for e in switches if e["t"] > t_sab and e["to"] == "ai"]  # handed back


def test_a_restore_is_sent_again_until_its_echo_agrees():
    """ParamGuard.restores on its own clock: a restore whose PARAM_VALUE echo has not come is
    sent again once per RESTORE_RETRY_S (never a flood); once the echo agrees nothing is sent;
    a new sabotage is set back at once; a value that broke a rule from the start (no safe value
    known) is the operator's, never set by the net."""
    from skyherd.safety.consistency import ParamGuard

    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    g = ParamGuard(spec)
    assert g.load(0.0, {"MPC_XY_VEL_MAX": 12.0, "MPC_TILTMAX_AIR": 10.0}) != ""  # tilt: too low
    assert g.restores(0.0) == {}  # the tilt was never safe: left to the operator
    g.update(1.0, "MPC_XY_VEL_MAX", 18.0)
    assert "MPC_XY_VEL_MAX" in g.problems
    assert g.restores(1.0) == {"MPC_XY_VEL_MAX": 12.0}
    assert g.restores(1.0 + 0.5 * RESTORE_RETRY_S) == {}
    assert g.restores(1.0 + RESTORE_RETRY_S) == {"MPC_XY_VEL_MAX": 12.0}  # no echo yet
    g.update(2.5, "MPC_XY_VEL_MAX", 12.0)  # the echo
    assert "MPC_XY_VEL_MAX" not in g.problems
    assert g.restores(5.0) == {}
    g.update(5.1, "MPC_XY_VEL_MAX", 16.0)  # sabotaged again
    assert g.restores(5.1) == {"MPC_XY_VEL_MAX": 12.0}


def test_gps_guard_restarts_after_a_telemetry_gap():
    """A cut link freezes the state the net sees; the first fresh state after it is not a
    GPS jump (the vehicle moved meanwhile), but a step without a gap still is."""
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    assert sp.gps_jump_m > 0
    sup = Supervisor(spec.envelope(), sp)
    q = np.array([1.0, 0, 0, 0])

    def st(t, p):
        return VehicleState(t, np.array(p, float), np.zeros(3), q, np.zeros(3), np.zeros(3), False)

    for k in range(50):
        sup._position_check(st(0.02 * k, [0, 0, -20]))
    assert sup._position_check(st(5.0, [sp.gps_jump_m + 3.0, 0, -20])) == ""  # after a 4 s gap
    assert not sup.position_suspect
    why = sup._position_check(st(5.02, [2 * sp.gps_jump_m + 6.0, 0, -20]))  # a step, no gap
    assert why.startswith("position jumped") and sup.position_suspect
