"""Parameter sabotage and its restore (safety.drills.run_drill, safety.campaign).

A client sets COM_OF_LOSS_T or MPC_XY_VEL_MAX mid-push; the net falls back with the reason
(safety.consistency). The net never sets the parameter back itself (a value a ground station
or an operator set is theirs to undo): it waits, and when another client sets it back, it
re-checks at that PARAM_VALUE and hands back to the AI."""

from __future__ import annotations

import dataclasses

import numpy as np

from skyherd.flight.state import VehicleState
from skyherd.safety.campaign import drill_rng, make_drill, make_vehicle
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.drills import DrillParams, run_drill
from skyherd.safety.supervisor import Supervisor, SupervisorParams


def _quad(index: int, seed: int = 52):
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    d = make_drill("param_sabotage", index, drill_rng(seed, "quadrotor", index), spec, p)
    return d, sp, p


def test_restored_parameter_hands_back_to_the_ai():
    """Drill 0015 (seed 52): COM_OF_LOSS_T = 4.5 s, a link cut, then a client sets 0.5 s back.
    Before the GPS guard restarted its dead reckoning after a telemetry gap, the position after
    the cut looked like a 3.8 m GPS jump and the net never handed back."""
    d, sp, p = _quad(15)
    (t_s, name, bad), (t_r, name_r, value) = d.script.params
    assert name == name_r == "COM_OF_LOSS_T" and value is None and t_r > d.script.link_cut[1]
    ap = make_vehicle(d, 52)
    good = ap.get_param(name)
    r = run_drill(d.script, ap, d.spec, sp, p)
    assert r.passed, r.why
    assert any("autopilot parameters: COM_OF_LOSS_T" in x for x in r.reasons)
    assert r.restored.startswith("handed back"), r.restored
    assert ap.get_param(name) == good  # the client's restore, to the value before


def test_without_a_restore_the_net_waits_and_never_sets_it_back():
    d, sp, p = _quad(15)
    (t_s, name, bad), _ = d.script.params
    script = dataclasses.replace(d.script, params=((t_s, name, bad),), must_recover=False)
    ap = make_vehicle(d, 52)
    events = []

    class Sink:
        def write(self, rec):
            events.append(rec)

    r = run_drill(script, ap, d.spec, sp, p, Sink())
    assert r.restored == ""
    assert ap.get_param(name) == bad  # the companion did not touch it
    switches = [e for e in events if e["event"] == "switch"]
    assert switches and switches[0]["reason"].startswith("autopilot parameters")
    t_sab = d.script.handover_s + t_s
    assert not [e for e in switches if e["t"] > t_sab and e["to"] == "ai"]  # waits


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
