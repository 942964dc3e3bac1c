"""The drills are judged by safety/judge.py: the flight's checks on the drill's truth, and the
drill's own (failsafe, caught, recovered) on hand-made records; the vectorized fence measure
against the compiled one; the campaign's exit rule and its Clopper–Pearson bound."""

import dataclasses
import math

import numpy as np
import pytest
from scipy.stats import binom

from skyherd.safety.campaign import breach_upper_bound, drills_needed
from skyherd.safety.campaign_verdict import bounds, summarize
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.envelope import NZ, SignedDistance
from skyherd.safety.judge import (
    Ending,
    Expect,
    ModeChange,
    NetRecord,
    Truth,
    answered,
    clearances,
    first_failed,
    judge,
    verdict,
    worst_rows,
)

NORTH = 35.0


@pytest.fixture(scope="module")
def spec(north35_spec):
    return north35_spec


def drill_truth(north=(0.0, 20.0, 0.0), alt=20.0, modes=("OFFBOARD",) * 3, t_end=30.0):
    """A drill from its hand-over at 10 s: in the air, north along `north` at 10/20/30 s."""
    t = np.arange(10.0, t_end + 1e-9, 0.02)
    n = np.interp(t, [10.0, 20.0, 30.0], north)
    pos = np.stack([n, np.zeros_like(t), np.full_like(t, -alt)], axis=1)
    mode = tuple(modes[min(int((x - 10.0) * 3 // 20.0), 2)] for x in t)  # in thirds
    return Truth(t, pos, np.ones(len(t), bool), mode)


def run(spec, truth, expect=None, net=None, changes=(), frames=None, ending=None):
    expect = Expect() if expect is None else expect
    net = NetRecord(reasons=("field edge 1",)) if net is None else net
    ending = ending or Ending(land=False, failsafe=net.yielded)
    checks = judge(truth, spec, changes, (10.0, truth.t[-1]), frames, len(truth.t), ending,
                   expect=expect, net=net)  # fmt: skip
    return {c.name: c for c in checks}, checks


def test_a_drill_is_judged_by_the_flights_checks_then_its_own(spec):
    by, checks = run(spec, drill_truth())
    assert [c.name for c in checks] == ["fence", "armed", "modes", "camera", "end", "mission",
                                        "failsafe", "caught", "recovered"]  # fmt: skip
    assert all(c.ok for c in checks) and verdict(checks) == "completed"
    assert by["fence"].value == pytest.approx(15.0)  # the fence 15 m north of the far end
    with pytest.raises(ValueError, match="both"):
        judge(drill_truth(), spec, (), None, None, 0, Ending(), expect=Expect())


def test_a_drill_breach_is_the_fences_and_named_first(spec):
    by, checks = run(spec, drill_truth(north=(0.0, NORTH + 2.0, 0.0)))
    assert first_failed(checks) is by["fence"] and by["fence"].value == pytest.approx(-2.0)
    assert verdict(checks).startswith("failed: fence: closest clearance -2.00 m at t = 20.0 s")
    tol = NetRecord(reasons=("x",), tolerance_m=2.5)  # the set's breach_tolerance_m
    assert run(spec, drill_truth(north=(0.0, NORTH + 2.0, 0.0)), net=tol)[0]["fence"].ok


def test_after_a_yield_the_net_answers_only_until_its_stopping_time(spec):
    """The autopilot's RTL home across the fence after the yield: reported, not failed; its
    own HOLD beyond the fence: failed (the failsafe check); the net's own flight: the fence."""
    truth = drill_truth(north=(0.0, 30.0, NORTH + 4.0), modes=("OFFBOARD", "OFFBOARD", "RTL"))
    yielded = NetRecord(("x",), "RTL", 20.0, 23.0)
    ch = [ModeChange(20.0, "RTL", True, False)]
    by, checks = run(spec, truth, net=yielded, changes=ch)
    assert all(c.ok for c in checks), verdict(checks)
    assert "path crossed the fence: reported" in by["failsafe"].reason
    assert "its own flight -4.00 m" in by["failsafe"].figure
    hold = drill_truth(north=(0.0, 30.0, NORTH + 4.0), modes=("OFFBOARD", "OFFBOARD", "HOLD"))
    by, checks = run(spec, hold, net=dataclasses.replace(yielded, yielded="HOLD"),
                     changes=[ModeChange(20.0, "HOLD", True, False)])  # fmt: skip
    assert (
        first_failed(checks) is by["failsafe"]
        and "own HOLD after the yield" in by["failsafe"].reason
    )
    late = NetRecord(("x",))  # a net that never yielded: the RTL track is its own
    assert not run(spec, truth, net=late, changes=ch)[0]["fence"].ok


def track_truth(points, modes, t0=10.0, dt=0.02):
    """A hand-made truth through (t, north, east) points, linear between them, at 20 m;
    modes: (t_from, mode) in order."""
    pts = np.asarray(points, float)
    t = np.arange(t0, pts[-1, 0] + 1e-9, dt)
    pos = np.stack([np.interp(t, pts[:, 0], pts[:, 1]), np.interp(t, pts[:, 0], pts[:, 2]),
                    np.full_like(t, -20.0)], axis=1)  # fmt: skip
    mode = tuple(next(m for tm, m in reversed(modes) if x >= tm - 1e-9) for x in t)
    return Truth(t, pos, np.ones(len(t), bool), mode)


RTL_AT_20 = NetRecord(("x",), "RTL", 20.0, 23.8)  # a yield at 20 s, answers up to 23.8 s


def test_after_an_rtl_yield_the_net_answers_for_the_stop_it_handed_over(spec):
    """The net's momentum across the fence after a yield to RTL is the net's breach: at 8 m/s
    3 m short of the fence (north 35), the vehicle brakes at 4 m/s² along its path (8 m) and
    overshoots 5 m, then RTL brings it home. Eq. 3's reach at 8 m/s: 0.3 x 8 + 64 / 5 = 15.2 m."""
    run_in = track_truth([(10, -48, 0), (20, 32, 0), (22, 40, 0), (30, 0, 0)],
                         [(10, "OFFBOARD"), (20, "RTL")])  # fmt: skip
    ch = [ModeChange(20.0, "RTL", True, False)]
    by, checks = run(spec, run_in, net=RTL_AT_20, changes=ch)
    assert first_failed(checks) is by["fence"] and by["fence"].value == pytest.approx(-5.0)
    assert answered(run_in, spec, RTL_AT_20)[run_in.t <= 23.8].all()  # all on its braking path


def test_after_an_rtl_yield_its_turn_across_a_boundary_is_the_autopilots_path(spec):
    """Flying east at 8 m/s, 5 m inside the fence, the net yields to RTL, which turns north
    across the fence 1 s later (home beyond it, say): 6 m off the braking path east at the
    breach (margin 2 m): the autopilot's line home, reported; the same track in the
    autopilot's own HOLD fails (the failsafe check), and in OFFBOARD (the net's) the fence."""
    turn = track_truth([(10, 30, -80), (20, 30, 0), (21, 30, 6), (23, 39, 6), (30, 39, 6)],
                       [(10, "OFFBOARD"), (20, "RTL")])  # fmt: skip
    ch = [ModeChange(20.0, "RTL", True, False)]
    by, checks = run(spec, turn, net=RTL_AT_20, changes=ch)
    assert all(c.ok for c in checks), verdict(checks)
    assert "path crossed the fence: reported" in by["failsafe"].reason
    assert "its own flight -4.00 m from the fence at worst (RTL)" in by["failsafe"].figure
    mask = answered(turn, spec, RTL_AT_20)
    assert not mask[(turn.t > 21.5) & (turn.t <= 23.8)].any() and mask[turn.t <= 20.9].all()
    hold = Truth(turn.t, turn.pos_ned, turn.armed,
                 tuple("HOLD" if m == "RTL" else m for m in turn.mode))  # fmt: skip
    by, checks = run(spec, hold, net=dataclasses.replace(RTL_AT_20, yielded="HOLD"),
                     changes=[ModeChange(20.0, "HOLD", True, False)])  # fmt: skip
    assert first_failed(checks) is by["fence"]  # HOLD: the whole window is the net's
    ours = Truth(turn.t, turn.pos_ned, turn.armed, ("OFFBOARD",) * len(turn.t))
    by, checks = run(spec, ours, net=RTL_AT_20, changes=ch)
    assert first_failed(checks) is by["fence"]  # not in RTL / LAND: the net's


def test_a_vehicle_that_cannot_stop_answers_for_its_whole_window(spec):
    """decel_h 0 (a fixed-wing's set): no braking path, the whole run-on window is the net's."""
    turn = track_truth([(10, 30, -80), (20, 30, 0), (21, 30, 6), (23, 39, 6), (30, 39, 6)],
                       [(10, "OFFBOARD"), (20, "RTL")])  # fmt: skip
    glide = dataclasses.replace(spec, dynamics=dataclasses.replace(spec.dynamics, decel_h_mps2=0.0))
    assert answered(turn, glide, RTL_AT_20)[turn.t <= 23.8].all()


def test_the_net_never_undoes_the_autopilots_failsafe(spec):
    ch = [ModeChange(12.0, "HOLD", True, True), ModeChange(15.0, "RTL", True, False),
          ModeChange(16.0, "OFFBOARD", True, True)]  # fmt: skip
    by, checks = run(spec, drill_truth(), net=NetRecord(("x",), "RTL", 15.0, 18.0), changes=ch)
    assert first_failed(checks) is by["modes"]
    assert by["modes"].reason == "the net overrode the autopilot's own mode 1 times"
    by, _ = run(spec, drill_truth(), net=NetRecord(("x",), "RTL", 15.0, 18.0), changes=ch[:2])
    assert by["modes"].ok  # a flight (no Expect) would fail it: test_safety_judge
    assert not judge(drill_truth(), spec, ch[:2], (10.0, 30.0), None, 0, Ending(land=False))[2].ok


def test_the_drill_demands_its_catch_its_failsafe_and_its_recovery(spec):
    want = Expect(reasons=("ceiling",))
    by, checks = run(spec, drill_truth(), expect=want)
    assert first_failed(checks) is by["caught"]
    assert (
        by["caught"].reason
        == "expected a fallback or projection for ('ceiling',), got ['field edge 1']"
    )
    assert run(spec, drill_truth(), expect=dataclasses.replace(want, catch=False))[0]["caught"].ok
    by, _ = run(spec, drill_truth(), expect=Expect(failsafe=True))
    assert not by["failsafe"].ok and by["failsafe"].figure == "the net never yielded"
    stuck = NetRecord(("field edge 1",), end_mode="fallback")
    by, checks = run(spec, drill_truth(), net=stuck)
    assert (
        first_failed(checks) is by["recovered"]
        and by["recovered"].reason == "not recovered: fallback at the end"
    )
    assert run(spec, drill_truth(), expect=Expect(recover=False), net=stuck)[0]["recovered"].ok
    restore = Expect(restore_t=8.0)
    by, _ = run(spec, drill_truth(), expect=restore)
    assert not by["recovered"].ok and "did not hand back" in by["recovered"].reason
    by, _ = run(spec, drill_truth(), expect=restore, net=NetRecord(("x",), ai_after_restore=9.5))
    assert by["recovered"].ok and by["recovered"].figure == "handed back 1.5 s after the restore"


def test_the_drill_ends_in_the_air_in_the_nets_mode_or_the_autopilots_failsafe(spec):
    by, _ = run(spec, drill_truth(modes=("OFFBOARD",) * 3))
    assert by["end"].ok
    by, _ = run(spec, drill_truth(modes=("OFFBOARD", "OFFBOARD", "POSCTL")))
    assert not by["end"].ok  # neither the net's mode nor a failsafe the net yielded to


@pytest.mark.parametrize("airframe", ["quadrotor", "fixedwing"])
def test_the_vectorized_fence_measure_is_the_compiled_one(airframe):
    """worst_rows (numpy, all samples at once) against Envelope.worst (compiled, one state),
    and the clearance against SignedDistance, on points in and around the field set."""
    spec, _ = load_envelope(default_envelope_path(airframe))
    geo, signed = spec.geometry(), SignedDistance(spec)
    rng = np.random.default_rng(3)
    span = np.abs(np.concatenate([z.points for z in spec.inclusions])).max() * 1.3
    lim = spec.limits
    pos = np.c_[
        rng.uniform(-span, span, (400, 2)), -rng.uniform(lim.floor_m + 1, lim.ceiling_m - 1, 400)
    ]
    z = np.zeros((400, NZ))
    z[:, 0:3] = pos
    assert np.allclose(worst_rows(geo, z), [geo.worst(x) for x in z])
    truth = Truth(np.arange(400.0), pos, np.ones(400, bool), ("OFFBOARD",) * 400)
    c, _ = clearances(truth, spec, (0.0, 400.0))
    assert np.allclose(c, [-signed(p) for p in pos])
    z[5, 1] = math.nan
    assert math.isnan(worst_rows(geo, z)[5])


def test_clopper_pearson_closed_form_and_beta_quantile():
    for n in (1, 10, 1000, 2000):
        assert breach_upper_bound(0, n) == pytest.approx(1 - 0.05 ** (1 / n), rel=1e-12)
    assert breach_upper_bound(0, 1000) == pytest.approx(2.9912e-3, rel=1e-4)  # rule of three: ~3/n
    for k, n, known in ((1, 10, 0.39416), (1, 20, 0.21611), (2, 10, 0.50690)):
        ub = breach_upper_bound(k, n)
        assert ub == pytest.approx(known, rel=1e-4)
        assert binom.cdf(k, n, ub) == pytest.approx(0.05, abs=1e-9)  # its definition
    assert breach_upper_bound(3, 3) == 1.0 and breach_upper_bound(0, 0) == 1.0
    assert drills_needed(1e-3) == 2995 and drills_needed(1e-2) == 299
    assert breach_upper_bound(0, 2995) <= 1e-3 < breach_upper_bound(0, 2994)
    with pytest.raises(ValueError):
        drills_needed(0.0)
    with pytest.raises(ValueError):
        breach_upper_bound(4, 3)


def _row(drill, kind="wind", passed=True, failed_check="", **kw):
    return {"drill": drill, "airframe": "quadrotor", "kind": kind, "passed": passed,
            "failed_check": failed_check, "min_clearance_m": 3.0, "breach": False,
            "overridden": 0, "yielded": "", "autopilot_excursion_m": "",
            "autopilot_excursion_mode": "", "first_reason": "", "not_recovered": False,
            "_tol": 0.0} | kw  # fmt: skip


def test_the_campaign_exits_on_any_failed_check_and_bounds_the_breaches():
    ok = [_row(f"wind {i:04d}") for i in range(3)]
    _, _, totals, bad = summarize(ok)
    assert bad == 0 and "drills failing a check (first failed: none): 0" in totals
    caught = _row("wind 0003", passed=False, failed_check="caught")
    breach = _row(
        "wind 0004", passed=False, failed_check="fence", breach=True, min_clearance_m=-0.2
    )
    crash = _row("crashed 0005", kind="crash", passed=False, failed_check="crash",
                 min_clearance_m=math.nan)  # fmt: skip
    _, _, totals, bad = summarize(ok + [caught, breach, crash])
    assert bad == 3 and "(first failed: caught 1, crash 1, fence 1)" in totals
    text = bounds(ok + [breach, crash])
    rows = {tuple(c.strip() for c in ln.strip("|").split("|"))[:2]: [c.strip() for c in ln.strip("|").split("|")]
            for ln in text.splitlines() if ln.startswith("| quadrotor")}  # fmt: skip
    # the crash (index 5: the kinds in turn) counts as a breach of its own kind: wind
    assert rows[("quadrotor", "wind")][2:5] == ["5", "2", f"{breach_upper_bound(2, 5):.2e}"]
    assert rows[("quadrotor", "all")][5] == "-"  # breaches: no breach-free count to reach
    assert bounds(ok).count("| 2992 ") == 2  # 2,995 needed, 3 flown: per kind and in all
    assert "after 2,995 drills" in text
