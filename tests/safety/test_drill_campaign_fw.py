"""Campaign regressions for the fixed-wing (safety.campaign, replayed alone from their seed).

Run 2 of the campaign (seed 31) found the fixed-wing's own HOLD beyond the fence after a
NAV_LOITER_RAD sabotage and a link cut (the net had refused the AI at the PARAM_VALUE but could
not command through the cut link): drill 0104 by 62.7 m, 0146 by 208 m. The vehicle now flies
with the drill's fence uploaded and its HOLD circle fits inside it."""

from __future__ import annotations

import numpy as np
import pytest

from skyherd.safety.campaign import drill_rng, kinds_for, make_drill, make_vehicle
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.drills import DrillParams, recovery_allowance_s, run_drill
from skyherd.safety.supervisor import SupervisorParams


@pytest.mark.parametrize("index", [104, 146])
def test_loiter_radius_sabotage_then_link_cut_stays_inside(index):
    spec, table = load_envelope(default_envelope_path("fixedwing"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    kind = kinds_for("fixedwing")[index % len(kinds_for("fixedwing"))]
    assert kind == "param_sabotage"
    d = make_drill(kind, index, drill_rng(31, "fixedwing", index), spec, p)
    assert d.script.params[0][1] == "NAV_LOITER_RAD" and d.script.link_cut is not None
    ap = make_vehicle(d, 31)
    good = ap.get_param("NAV_LOITER_RAD")
    r = run_drill(d.script, ap, d.spec, sp, p)
    assert r.passed, r.why
    # the net set the radius back at its PARAM_VALUE (ParamGuard.restores): through the cut the
    # vehicle holds on a safe circle, the net's HOLD or the offboard-loss failsafe's
    assert ap.get_param("NAV_LOITER_RAD") == good
    assert r.yielded in ("", "HOLD")
    if r.yielded:
        assert r.autopilot_excursion_m < -10.0  # its own circle stayed well inside
    assert r.min_clearance_m > 10.0


def _fw_drill(index: int, seed: int, kind: str):
    spec, table = load_envelope(default_envelope_path("fixedwing"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    assert kinds_for("fixedwing")[index % len(kinds_for("fixedwing"))] == kind
    d = make_drill(kind, index, drill_rng(seed, "fixedwing", index), spec, p)
    return d, spec, sp, p


def test_wind_0208_seed_52_stays_above_the_floor():
    """Campaign run 3's one breach: a 9 m/s tailwind (+ 2 m/s gusts) stepped in at the drill's
    start took the J3Cub below stall; the recovery flew FW_AIRSPD_MIN, slewed its climb demand
    into a descent while sinking, and passed 12.2 m below the 30 m floor. Now the aircraft starts
    trimmed in the air mass, the vertical gusts follow the stated model, the recovery flies trim
    airspeed and climbs, and the floor row keeps the gust sink reserve."""
    d, spec, sp, p = _fw_drill(208, 52, "wind")
    assert max(abs(x) for x in d.faults.wind.mean_ned) > 8.0  # still the 9 m/s tailwind drill
    assert d.faults.wind.gust_std > 1.9
    ap = make_vehicle(d, 52)
    r = run_drill(d.script, ap, d.spec, sp, p)
    assert r.passed, r.why
    assert r.min_clearance_m > 5.0  # was -12.2 m (through the floor)


def test_air_start_in_wind_is_trimmed_in_the_air_mass():
    """No wind step at the start: the airspeed at the first steps is the trim airspeed, not the
    trim airspeed minus the tailwind (15 m/s, below the 17.5 m/s stall, before the fix)."""
    d, spec, sp, p = _fw_drill(208, 52, "wind")
    ap = make_vehicle(d, 52)
    ap.start_in_air(-float(d.script.start_ned[2]), p.fixedwing_speed_mps, d.script.start_heading)
    speeds = []
    for _ in range(25):  # 0.5 s
        ap.step()
        speeds.append(ap.model.airspeed)
    assert min(speeds) > p.fixedwing_speed_mps - 2.5, speeds
    ground = float(np.hypot(*ap.true_state.vel_ned[:2]))
    assert abs(ground - p.fixedwing_speed_mps) > 5.0  # the ground speed carries the wind


def test_fixedwing_drill_must_recover_and_gets_the_time_to():
    """Issue 26: fixed-wing campaign drills were not judged on the AI flying at the end ("too
    slow"), which hid that their well-behaved AI orbited home, 30-250 m inside the certified
    boundary: max_speed 0000 (seed 61) was handed back at 24.3 s, then the orbit crossed the
    fence rows again ("field edge 4" at 53.3 s) and the net flew to the end. The AI now orbits
    the middle of the field, the drill runs at least the airframe's recovery allowance after
    the attack (recovery_allowance_s: 46 s) and must end with the AI flying."""
    d, spec, sp, p = _fw_drill(0, 61, "max_speed")
    assert d.script.must_recover
    allowance = recovery_allowance_s(d.spec, sp)
    assert allowance == pytest.approx(6.0 + 18.2 + 450.0 / 24.0 + 3.0, abs=0.1)
    assert d.script.duration_s < d.script.t_off + allowance  # the rule lengthens this drill
    r = run_drill(d.script, make_vehicle(d, 61), d.spec, sp, p)
    assert r.passed, r.why
    assert r.track["t"][-1] >= d.script.t_off + allowance - 0.05
    assert r.track["mode"][-1] == 0  # the AI flies at the end
    assert r.switches == 3  # fallback, recovery, AI: once
