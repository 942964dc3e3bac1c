"""skyherd.policy.shepherd: Strömbom's sub-skills, the herding episodes, the learned selector."""

import json
import math

import numpy as np
import pytest

from skyherd.groundsim.flock import FlockParams
from skyherd.policy.shepherd import study
from skyherd.policy.shepherd.episode import run_episode
from skyherd.policy.shepherd.rules import (
    COLLECT,
    DRIVE,
    ShepherdParams,
    cohesion_radius,
    collect_point,
    drive_point,
    shepherd_velocity,
    strombom_rule,
)
from skyherd.policy.shepherd.selector import (
    SELECTOR_FILE,
    LearnedSelector,
    SelectorFitParams,
    StrombomSelector,
    train_selector,
)

F = FlockParams()


def test_the_sub_skills_points_in_closed_form():
    pos = np.array([[0.0, 0.0], [0.0, 2.0], [0.0, -2.0], [12.0, 0.0]] + [[0.0, 0.0]] * 6)
    g = pos.mean(axis=0)  # (1.2, 0)
    assert cohesion_radius(F) == pytest.approx(2.0 * 10 ** (2 / 3))
    np.testing.assert_allclose(collect_point(pos, F), [14.0, 0.0])  # r_a behind agent 3
    pd = drive_point(pos, (-20.0, 0.0), F)  # the goal due south: P_d north of the centre
    np.testing.assert_allclose(pd, [g[0] + 2.0 * math.sqrt(10), 0.0])
    assert strombom_rule(pos, F) == COLLECT  # 10.8 m > f(10) = 9.28 m
    assert strombom_rule(pos * 0.5, F) == DRIVE


def test_the_shepherd_stands_near_an_agent_and_flies_at_its_speed_otherwise():
    p = ShepherdParams()
    pos = np.array([[10.0, 0.0]] * 10)
    np.testing.assert_array_equal(shepherd_velocity([5.0, 0.0], [0, 0], pos, F, p), [0.0, 0.0])
    v = shepherd_velocity([-10.0, 0.0], [-10.0, 30.0], pos, F, p)
    np.testing.assert_allclose(v, [0.0, p.speed_mps])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_both_selectors_bring_the_flock_to_the_goal(seed):
    for sel in (StrombomSelector(), LearnedSelector.load()):
        ep = run_episode(seed, sel)
        assert ep.success and ep.time_to_goal_s < ShepherdParams().limit_s
        assert ep.spread_end_m < ep.spread_start_m


def test_without_a_shepherd_that_moves_the_flock_never_arrives():
    class Idle:
        def choose(self, pos, goal, flock):
            return COLLECT, 0.0

    ep = run_episode(0, Idle(), task=ShepherdParams(speed_mps=1e-9, limit_s=60.0))
    assert not ep.success and ep.time_to_goal_s is None


@pytest.mark.slow
def test_the_learned_selector_reproduces_from_its_demonstrations():
    kept = json.loads(SELECTOR_FILE.read_text())
    fit = SelectorFitParams(seeds=tuple(kept["fit"]["seeds"]))
    sel, rec = train_selector(fit)
    # 1e-6: the fit is deterministic; BLAS kernels of other CPUs round at ~1e-8 (seen: 5e-8)
    np.testing.assert_allclose(sel.w, kept["w"], rtol=1e-6)
    assert sel.b == pytest.approx(kept["b"], rel=1e-6)
    assert rec["train_accuracy"] >= 0.99 and rec["demonstrations"] == kept["demonstrations"]


def test_the_study_prints_a_table_and_writes_its_files(tmp_path):
    rows = study.run(seeds=4, first_seed=0, out=tmp_path)
    for name in ("strombom", "learned"):
        assert rows[name]["success"] == 4 and 0 < rows[name]["median_s"] < 400
    assert (tmp_path / "table.md").read_text().count("| 4/4 |") == 2
    assert len((tmp_path / "episodes.csv").read_text().splitlines()) == 1 + 8


def test_skyherd_study_shepherd_writes_a_run_folder_with_the_figure(tmp_path, capsys):
    from skyherd.scripts.cli import main

    assert main(["study", "shepherd", "--seeds", "2", "--runs-dir", str(tmp_path)]) == 0
    (run,) = tmp_path.iterdir()
    assert (run / "shepherd_study.png").stat().st_size > 10_000
    assert (run / "summary.md").read_text().count("| 2/2 |") == 2
    assert json.loads((run / "config.json").read_text())["seeds"] == 2
    assert main(["study", "shepherd", "--agents", "1", "--runs-dir", str(tmp_path)]) == 2
    assert "a flock has at least 2 agents" in capsys.readouterr().err


def test_skyherd_train_shepherd_writes_the_selector_it_reports(tmp_path, capsys):
    from skyherd.scripts.cli import main

    out = tmp_path / "selector.json"
    assert main(["train", "shepherd", "--episodes", "2", "--out", str(out)]) == 0
    kept = json.loads(out.read_text())
    assert kept["fit"]["seeds"] == [1000, 1001]
    assert f"{out}: {kept['demonstrations']} decisions" in capsys.readouterr().out
