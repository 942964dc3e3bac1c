"""Campaign regressions for the fixed-wing (safety.campaign, replayed alone from their seed).

Run 2 of the campaign (seed 31) found the fixed-wing's own HOLD beyond the fence after a
NAV_LOITER_RAD sabotage and a link cut (the net had refused the AI at the PARAM_VALUE but could
not command through the cut link): drill 0104 by 62.7 m, 0146 by 208 m. The vehicle now flies
with the drill's fence uploaded and its HOLD circle fits inside it."""

from __future__ import annotations

import pytest

from safety.campaign import drill_rng, kinds_for, make_drill, make_vehicle
from safety.config import default_envelope_path, fill_dataclass, load_envelope
from safety.drills import DrillParams, run_drill
from safety.supervisor import SupervisorParams


@pytest.mark.parametrize("index", [104, 146])
def test_loiter_radius_sabotage_then_link_cut_stays_inside(index):
    spec, table = load_envelope(default_envelope_path("fixedwing"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    kind = kinds_for("fixedwing")[index % len(kinds_for("fixedwing"))]
    assert kind == "param_sabotage"
    d = make_drill(kind, index, drill_rng(31, "fixedwing", index), spec, p)
    assert d.script.params[0][1] == "NAV_LOITER_RAD" and d.script.link_cut is not None
    r = run_drill(d.script, make_vehicle(d, 31), d.spec, sp, p)
    assert r.passed, r.why
    assert r.yielded == "HOLD"  # the offboard-loss failsafe took over during the cut ...
    assert r.autopilot_excursion_m < -10.0  # ... and its own circle stayed well inside
    assert r.min_clearance_m > 10.0
