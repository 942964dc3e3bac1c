"""The pre-registered rule of policy/education/prereg.py: verdicts and per-episode summary."""

import math

from policy.education.prereg import summarise, verdicts


def test_verdicts_follow_the_stated_rule():
    ab = {"all_in_view_frac": 0.962, "footprint_ratio": 10.503}
    ex = {"all_in_view_frac": 0.936, "footprint_ratio": 9.247}
    # session 5b's 10-episode figures: footprint closer to the expert, all-in-view 0.940 < 0.943
    v = verdicts({"all_in_view_frac": 0.940, "footprint_ratio": 9.654}, ab, ex)
    assert v == {"goal1_all_in_view": False, "goal2_footprint": True}
    # goal 2 compares with AB's distance to the expert (1.256), not the midpoint 9.875
    assert verdicts({"all_in_view_frac": 0.9, "footprint_ratio": 9.9}, ab, ex)["goal2_footprint"]
    v = verdicts({"all_in_view_frac": 0.943, "footprint_ratio": 10.6}, ab, ex)
    assert v == {"goal1_all_in_view": True, "goal2_footprint": False}


def test_summarise_drops_nan_and_gives_standard_error():
    eps = [
        {"all_in_view_frac": a, "footprint_ratio": f}
        for a, f in ((1.0, 2.0), (0.5, math.nan), (0.0, 4.0))
    ]
    s = summarise(eps)
    assert s["all_in_view_frac"]["mean"] == 0.5 and s["all_in_view_frac"]["n"] == 3
    assert math.isclose(s["all_in_view_frac"]["se"], 0.5 / math.sqrt(3))
    assert s["footprint_ratio"] == {"mean": 3.0, "se": 1.0, "n": 2}
