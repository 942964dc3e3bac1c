"""The pre-registered rule of policy/education/prereg.py: verdicts and per-episode summary."""

import math

import pytest

from skyherd.policy.education.prereg import summarise, verdicts


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


@pytest.mark.slow
def test_skyherd_evaluate_reproduces_the_recorded_ab_and_expert_figures(tmp_path):
    """The command on the kept AB policy as both sides: AB and the expert give the figures of
    docs/education.md (seeds 700000-700099), equal distances fail goal 2 (the rule is a strict
    <), so the exit code is 1; the run folder has results.json and the table."""
    import json
    from pathlib import Path

    from skyherd.scripts.cli import main

    ab = Path(__file__).resolve().parents[2] / "skyherd" / "policy" / "models" / "groundair_ab.npz"
    assert main(["evaluate", str(ab), "--ab", str(ab), "--runs-dir", str(tmp_path)]) == 1
    (run,) = tmp_path.iterdir()
    res = json.loads((run / "results.json").read_text())
    s = res["summary"]
    assert round(s["ab"]["all_in_view_frac"]["mean"], 4) == 0.9807
    assert round(s["ab"]["footprint_ratio"]["mean"], 3) == 8.066
    assert round(s["expert"]["all_in_view_frac"]["mean"], 4) == 0.9747
    assert round(s["expert"]["footprint_ratio"]["mean"], 3) == 7.359
    assert res["verdicts"] == {"goal1_all_in_view": True, "goal2_footprint": False}
    assert "FAILS" in (run / "summary.md").read_text()
    assert main(["evaluate", str(tmp_path / "none.npz"), "--ab", str(ab)]) == 2  # clear error
