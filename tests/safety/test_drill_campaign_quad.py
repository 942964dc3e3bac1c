"""Campaign regressions for the quadrotor and the campaign's exit rule (safety.campaign_verdict).

Run 3 (seed 51) found battery 0182: the autopilot's own battery RTL flew its straight line home
across a reflex corner of the notched field, 1.3 m beyond the fence, after the net had yielded.
PX4's RTL does the same (it does not route around a fence) and the net must never undo the
autopilot's failsafe: the campaign reports such a path in its own column and does not fail on it;
the autopilot's own HOLD beyond the fence (which the built-in vehicle fits to the fence) fails."""

from __future__ import annotations

from skyherd.safety.campaign import drill_rng, kinds_for, make_drill, make_vehicle
from skyherd.safety.campaign_verdict import summarize
from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
from skyherd.safety.drills import DrillParams, run_drill
from skyherd.safety.supervisor import SupervisorParams


def test_battery_0182_rtl_path_is_the_autopilots_and_reported():
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    ks = kinds_for("quadrotor")
    assert ks[182 % len(ks)] == "battery"
    d = make_drill("battery", 182, drill_rng(51, "quadrotor", 182), spec, p)
    r = run_drill(d.script, make_vehicle(d, 51), d.spec, sp, p)
    assert r.passed, r.why
    by = {c.name: c for c in r.checks}
    assert "path crossed the fence: reported" in by["failsafe"].reason  # the judge's words
    assert r.overridden == 0 and r.yielded == "RTL"  # the failsafe stood
    assert r.min_clearance_m > 0.0  # the net's own flight stayed inside
    assert r.autopilot_excursion_mode == "RTL"
    assert 0.0 < r.autopilot_excursion_m < 5.0  # RTL's straight line home cut the corner


def _row(drill, mode, excursion, **kw):
    return {"drill": drill, "airframe": "quadrotor", "kind": "battery", "passed": True,
            "failed_check": "", "min_clearance_m": 3.0, "breach": False, "overridden": 0,
            "yielded": mode, "autopilot_excursion_m": excursion, "autopilot_excursion_mode": mode,
            "first_reason": "", "_tol": 0.0} | kw  # fmt: skip


def test_exit_rule_counts_own_hold_not_rtl_path():
    """The judge's failsafe check fails an own HOLD beyond the fence and reports an RTL path
    (tests/safety/test_drill_judge.py); the campaign counts both columns and exits on the verdict."""
    rtl = [_row("a", "RTL", 1.3), _row("b", "LAND", -2.0), _row("c", "RTL", "")]
    table, _, totals, bad = summarize(rtl)
    assert bad == 0, totals
    assert "RTL/LAND path beyond the fence (reported, not failing): 1" in totals
    hold = rtl + [_row("d", "HOLD", 0.4, passed=False, failed_check="failsafe")]
    _, _, totals, bad = summarize(hold)
    assert bad == 1, totals
    assert "own HOLD after a yield beyond the fence: 1" in totals
    assert "(first failed: failsafe 1)" in totals
    breach = _row(
        "e", "", 0.0, breach=True, min_clearance_m=-0.2, passed=False, failed_check="fence"
    )
    _, _, _, bad = summarize(rtl + [breach])
    assert bad == 1  # the net's breach
    over = _row("f", "RTL", "", overridden=2, passed=False, failed_check="modes")
    _, _, totals, bad = summarize(rtl + [over])
    assert bad == 1 and "overridden autopilot failsafes: 2" in totals  # one drill failed
    crash = _row("g", "", "", kind="crash", passed=False, failed_check="crash",
                 min_clearance_m=float("nan"))  # fmt: skip
    _, _, totals, bad = summarize(rtl + [crash])
    assert bad == 1 and "crashed drills: 1" in totals  # an unjudged drill is never a pass


def test_wind_0365_seed_97_gets_its_recovery_allowance_after_the_last_fallback():
    """Campaign seed 97 (issue 26's re-run) found wind 0365: after the attack the behaving AI,
    in an 11 m/s crosswind, tilted past the 45° roll row at 19.6 s (after the hand-over); the
    drill ended at 22.3 s, the net in PID 1.5 s into its recovery ("not recovered"; main's code
    judged it the same). A drill judged on its recovery now runs a recovery allowance past the
    net's last switch out of AI (at most 3 allowances past its scripted end): the AI flies
    again at 26.1 s and stays; no breach either way (clearance 4.5 m)."""
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    d = make_drill("wind", 365, drill_rng(97, "quadrotor", 365), spec, p)
    r = run_drill(d.script, make_vehicle(d, 97), d.spec, sp, p)
    assert r.passed, r.why
    assert r.track["mode"][-1] == 0 and r.track["t"][-1] > d.script.duration_s + 4.0
    assert any("roll" in x for x in r.reasons) and r.min_clearance_m > 4.0


def test_seed_0_battery_rtl_turns_across_the_mast_and_barn_are_the_autopilots_path():
    """The 100,000-drill campaign (seed 0) failed 11 battery drills, each an RTL line home
    across the mast or the barn inside the net's run-on window after its yield (stop 41).
    Battery 43134: yielded 4 m beside the mast at 7 m/s, flying away from it; RTL turned home
    through it (-7.1 m). Battery 36134: the net's PID was flying home when RTL took over and
    clipped the barn's corner (-0.3 m). Neither is on the braking path the net handed over
    (safety.judge.answered): reported, not failed."""
    spec, table = load_envelope(default_envelope_path("quadrotor"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    for index, deep in ((43134, 6.0), (36134, 0.2)):  # the mast, the barn
        d = make_drill("battery", index, drill_rng(0, "quadrotor", index), spec, p)
        r = run_drill(d.script, make_vehicle(d, 0), d.spec, sp, p)
        assert r.passed, r.why
        assert r.yielded == "RTL" and r.overridden == 0
        assert r.min_clearance_m > 0.0  # the samples the net answers for stayed inside
        assert r.autopilot_excursion_mode == "RTL" and r.autopilot_excursion_m > deep
        assert (
            "path crossed the fence: reported" in {c.name: c for c in r.checks}["failsafe"].reason
        )
