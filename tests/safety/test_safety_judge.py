"""safety/judge.py on hand-made tracks: each check passes on a clean flight and fails, with its
figure, on the one thing it is there to catch (the through-`fly` cases: test_fly_judge.py)."""

import numpy as np
import pytest

from skyherd.safety.judge import Ending, JudgeParams, ModeChange, Truth, first_failed, judge

NORTH = 35.0  # the fence's north edge [m]


@pytest.fixture(scope="module")
def spec(north35_spec):
    return north35_spec


def flight(north_max=20.0, east_max=0.0, alt=20.0, dt=0.1, armed_until=None, mode="OFFBOARD"):
    """Armed at 0.5 s, take-off to `alt` (1-10 s), out to (north_max, east_max) and back (10-30 s), landing
    (30-40 s), disarmed after 40.5 s (or from `armed_until` on, wherever it is)."""
    t = np.arange(0.0, 42.0, dt)
    h = np.interp(t, [1, 10, 30, 40], [0, alt, alt, 0])
    s = np.interp(t, [10, 20, 30], [0, 1, 0])
    pos = np.stack([s * north_max, s * east_max, -h], axis=1)
    armed = (t > 0.5) & (t < 40.5)
    if armed_until is not None:
        armed &= t < armed_until
    modes = tuple("TAKEOFF" if x < 10 else mode if x < 30 else "LAND" for x in t)
    return Truth(t, pos, armed, modes)


def run(spec, truth, changes=(), window=(10.0, 30.0), frame_t=None, rendered=200,
        ending=None, net_modes=()):  # fmt: skip
    ending = Ending() if ending is None else ending
    checks = judge(truth, spec, changes, window, frame_t, rendered, ending, net_modes)
    return {c.name: c for c in checks}, checks


def test_a_clean_flight_passes_every_check_in_order(spec):
    by, checks = run(spec, flight(), frame_t=list(np.arange(10.0, 30.0, 0.1)))
    assert [c.name for c in checks] == ["fence", "armed", "modes", "camera", "end", "mission"]
    assert all(c.ok for c in checks) and first_failed(checks) is None
    # closest: the fence 15 m north of the track's far end, or the floor at the hand-over
    assert by["fence"].figure.startswith("closest clearance +15.00 m at t = ")


def test_the_truth_beyond_the_fence_fails_with_its_depth_and_time(spec):
    by, checks = run(spec, flight(north_max=NORTH + 3.0))
    f = by["fence"]
    assert not f.ok and first_failed(checks) is f
    assert f.figure.startswith("closest clearance -3.00 m at t = 20.0 s") and "north 35" in f.figure


def test_a_crossing_by_a_few_centimetres_is_a_crossing(spec):
    by, _ = run(spec, flight(north_max=NORTH + 0.05))
    assert not by["fence"].ok and "-0.05 m" in by["fence"].figure
    by, _ = run(spec, flight(north_max=NORTH - 0.05))
    assert by["fence"].ok and "+0.05 m" in by["fence"].figure


def test_an_exclusion_zone_entered_fails_naming_the_zone(spec):
    by, _ = run(spec, flight(north_max=0.0, east_max=95.0))  # 5 m into the 10 m tower circle
    assert not by["fence"].ok and "tower" in by["fence"].figure, by["fence"]


def test_the_ceiling_counts_always_the_floor_only_in_the_ai_phase(spec):
    by, _ = run(spec, flight(alt=61.0))
    assert (
        not by["fence"].ok and "-1.00 m" in by["fence"].figure and "ceiling" in by["fence"].figure
    )
    # take-off and landing cross the 5 m floor by design: outside the AI window it is not judged
    by, _ = run(spec, flight(alt=20.0))
    assert by["fence"].ok
    low = flight(alt=4.0)  # the AI phase flown 1 m under the floor
    by, _ = run(spec, low)
    assert not by["fence"].ok and "floor" in by["fence"].figure and "-1.00 m" in by["fence"].figure
    # a mission flown without a net (the square) has no floor to keep
    no_net = judge(low, spec, (), (10.0, 30.0), None, 0, Ending(), p=JudgeParams(floor=False))
    assert no_net[0].ok


def test_outside_the_fence_on_the_ground_is_not_a_breach(spec):
    truth = flight(alt=0.0, north_max=NORTH + 10)  # never airborne
    by, _ = run(spec, truth, window=None)
    assert by["fence"].ok and by["fence"].figure == "never airborne"


def test_a_disarm_in_the_air_fails_on_the_truth_or_on_a_heartbeat(spec):
    by, checks = run(spec, flight(armed_until=20.0))
    assert not by["armed"].ok and by["armed"].figure == "disarmed at 20.0 m, t = 20.0 s"
    # a disarm and re-arm between two truth samples: the companion's heartbeat still saw it
    seen = [ModeChange(20.03, "OFFBOARD", False, False, alt_m=20.0)]
    by, _ = run(spec, flight(), changes=seen)
    assert not by["armed"].ok and "(heartbeat)" in by["armed"].figure
    # the landing's disarm on the ground is no failure
    by, _ = run(spec, flight(), changes=[ModeChange(40.5, "LAND", False, None, alt_m=0.0)])
    assert by["armed"].ok


def test_a_mode_change_not_the_companions_fails_even_when_it_changed_back(spec):
    changes = [
        ModeChange(9.9, "OFFBOARD", True, None),  # the hand-over's own steps: not judged
        ModeChange(15.0, "HOLD", True, True),  # the net's fallback: asked for
        ModeChange(15.02, "RTL", True, False),  # a ground station's RTL ...
        ModeChange(15.07, "OFFBOARD", True, False),  # ... and back, before the next tick
    ]
    by, checks = run(spec, flight(), changes=changes)
    m = by["modes"]
    assert not m.ok and first_failed(checks) is m
    assert m.figure == "RTL at t = 15.02 s, then OFFBOARD at t = 15.07 s"
    assert "2 of 3" in m.reason
    by, _ = run(spec, flight(), changes=changes[:2])
    assert by["modes"].ok


def test_no_frames_fails_the_camera_blind_or_held(spec):
    by, checks = run(spec, flight(), frame_t=[])
    c = by["camera"]
    assert not c.ok and first_failed(checks) is c and c.reason.startswith("blind")
    assert (
        c.figure
        == "0 of 200 frames, longest gap 20.0 s from t = 10.0 s, camera lost 100 % of the AI phase"
    )
    # the net caught it (fallback 1.1 s after the hand-over) and held: safe, but no job done
    by, _ = run(spec, flight(), frame_t=[], net_modes=[(11.1, "fallback")])
    assert not by["camera"].ok and "lost for more than 50 %" in by["camera"].reason


def test_too_few_frames_fail_the_camera(spec):
    frames = [t for t in np.arange(10.0, 30.0, 0.1) if round(t * 10) % 10 != 0]  # 90 % ...
    by, _ = run(spec, flight(), frame_t=frames[:-4])  # ... less 4 frames
    assert not by["camera"].ok and by["camera"].reason.startswith("88 % of the frames arrived")


def test_a_camera_cut_the_net_caught_passes_and_its_frames_are_not_counted_missing(spec):
    """A 3 s cut in a 20 s AI phase (85 % of the frames): caught, and outside it every frame."""
    frames = [t for t in np.arange(10.0, 30.0, 0.1) if not 16.0 < t < 19.05]
    by, _ = run(spec, flight(), frame_t=frames, net_modes=[(17.1, "fallback"), (20.5, "ai")])
    assert by["camera"].ok and "caught by the net" in by["camera"].reason, by["camera"]
    assert "camera lost 15 % of the AI phase" in by["camera"].figure


def test_a_camera_gap_is_a_failure_unless_the_net_caught_it(spec):
    frames = [t for t in np.arange(10.0, 30.0, 0.1) if not 20.0 < t < 21.55]  # 20.0 -> 21.6 s
    caught = [(21.1, "fallback"), (22.1, "pid"), (24.0, "ai")]
    by, _ = run(spec, flight(), frame_t=frames, net_modes=caught)
    assert by["camera"].ok and "caught by the net" in by["camera"].reason
    by, _ = run(spec, flight(), frame_t=frames, net_modes=[])
    assert not by["camera"].ok and by["camera"].reason.startswith(
        "blind: no frame for 1.6 s from t = 20.0 s"
    )
    # a gap within the timeout and the detection time is no event
    short = [t for t in np.arange(10.0, 30.0, 0.1) if not 20.0 < t < 21.15]
    assert run(spec, flight(), frame_t=short)[0]["camera"].ok


def test_the_end_landed_and_disarmed_or_the_orbits_documented_end(spec):
    by, _ = run(spec, flight())
    assert by["end"].ok and by["end"].figure == "0.00 m, disarmed, LAND at t = 41.9 s"
    t = flight()
    hover = Truth(t.t[:250], t.pos_ned[:250], t.armed[:250], t.mode[:250])  # ends at 24.9 s, 20 m
    by, _ = run(spec, hover)
    assert not by["end"].ok and by["end"].reason == "not landed and disarmed"
    no_land = Ending(land=False)  # the fixed-wing orbit with --orbit-no-land (docs/orbit.md)
    assert run(spec, hover, ending=no_land)[0]["end"].ok
    assert not run(spec, flight(), ending=no_land)[0]["end"].ok


def test_arduplanes_documented_end_is_rtl_in_the_air(spec):
    """ArduPlane has no LAND mode: its landing recipe is RTL (hil.autopilots.ArduPlaneProfile),
    so the end check accepts armed in the air in RTL, and only that (flown against real
    ArduPlane: make test-autopilots' orbit ended 94.61 m, armed, RTL)."""
    rtl = Ending(end_mode="RTL")
    t = flight(mode="RTL")
    hover = Truth(t.t[:250], t.pos_ned[:250], t.armed[:250], t.mode[:250])  # 20 m, armed, RTL
    by, _ = run(spec, hover, ending=rtl)
    assert (
        by["end"].ok
        and by["end"].reason == "in its documented end: armed in the air in RTL (it does not land)"
    )
    loiter = Truth(hover.t, hover.pos_ned, hover.armed, ("LOITER",) * len(hover.t))
    assert not run(spec, loiter, ending=rtl)[0]["end"].ok  # any other mode fails
    assert not run(spec, flight(mode="RTL"), ending=rtl)[0][
        "end"
    ].ok  # on the ground: not RTL's end


def test_the_missions_own_outcome_is_the_last_check(spec):
    by, checks = run(spec, flight(), ending=Ending("aborted", "link lost"))
    assert first_failed(checks) is by["mission"] and by["mission"].reason == "link lost"
