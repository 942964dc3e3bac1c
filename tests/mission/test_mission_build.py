"""mission.build: the companion's missions from a MissionChoice, without argparse."""

import pytest

from skyherd.mission.build import MissionChoice, build_mission, load_pilot_policy
from skyherd.policy.shepherd.rules import ShepherdParams
from skyherd.task.params import TaskParams


def test_each_mission_decides_at_its_pilots_own_period():
    """The plan's decision period is the policy's own parameter, never a second copy."""
    _, plan = build_mission(MissionChoice(), None)
    assert plan.decision_s == TaskParams().dt_s and plan.altitude_m == 20.0
    _, plan = build_mission(MissionChoice(mission="shepherd"), None)
    assert plan.decision_s == ShepherdParams().decision_s and plan.altitude_m == 12.0
    _, plan = build_mission(MissionChoice(mission="square", altitude_m=30.0, side_m=10.0), None)
    assert plan.altitude_m == 30.0


def test_bad_choices_are_one_line_value_errors(tmp_path):
    with pytest.raises(ValueError, match="--side"):
        build_mission(MissionChoice(mission="square", side_m=0.0), None)
    with pytest.raises(ValueError, match="no such drill"):
        build_mission(MissionChoice(pilot="drill:nothing-like-it"), None)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a policy")
    with pytest.raises(ValueError, match="train one"):
        load_pilot_policy(str(bad))


def test_records_go_to_the_run_folder(tmp_path):
    build_mission(MissionChoice(pilot="pid"), tmp_path)
    assert (tmp_path / "metrics.csv").exists() and (tmp_path / "decisions.jsonl").exists()
