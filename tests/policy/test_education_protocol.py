"""policy.education.course and policy.education.evaluation without the command line: one seed
taught on a one-lesson curriculum, its lessons.csv rows read back, the hyper-parameters read back
from config.json, and the evaluation protocol on the taught policy."""

import csv
import dataclasses
import json

import numpy as np
import pytest

from skyherd.policy.dqn import load_policy
from skyherd.policy.education import course
from skyherd.policy.education import evaluation as E
from skyherd.policy.education.modular import ModularPolicy
from skyherd.policy.education.teach import QUICK, EduParams
from skyherd.policy.education.timeline import parse_record, timeline
from skyherd.runio.decisions import KEYS
from skyherd.runio.runfolder import CsvWriter, to_jsonable
from skyherd.task.params import ACTION_NAMES, TaskParams, action_velocity_ned

ONE = """
format = "skyherd-curriculum/1"
name = "one"
version = "0.1"
[concepts.spread_error]
formula = "spread - SPREAD_TARGET"
unit = "image half-diagonal"
[concepts.too_tight]
formula = "spread_error < -0.06"
unit = "bool"

[[lessons]]  # a lone skill lesson: no composite, the module flies alone
name = "descend"
teaches = ["spread_error", "too_tight"]
scenario = "descend"
module = "descend"
method = "dqn"
inputs = ["spread_error"]
actions = ["hover", "descend"]
pass = {all_in_view_frac = ">= 0.0"}
reward = {all_in_view = 1.0, spread_15_30 = 0.3, spread_30_45 = 0.7}
"""


@pytest.fixture(scope="module")
def taught(tmp_path_factory):
    """One seed of the one-lesson course, the monolith beside it: (job, out)."""
    d = tmp_path_factory.mktemp("course")
    (d / "one.toml").write_text(ONE)
    (d / "policies").mkdir()
    job = course.SeedJob(d / "one.toml", QUICK, 4, d / "policies")
    return job, course.teach_seed(job)


def test_one_seed_is_taught_and_its_policies_saved(taught):
    job, out = taught
    assert out["seed"] == 4 and set(out) == {"seed", "educated", "monolith"}
    (lesson,) = out["educated"]
    assert lesson["lesson"] == "descend" and set(lesson["retention"]) == {"descend"}
    json.dumps(out)  # plain data only: what a worker process sends back
    pol = load_policy(job.policy_dir / "educated_seed4.npz")
    assert isinstance(pol, ModularPolicy) and set(pol.modules) == {"descend"}
    mono = load_policy(job.policy_dir / "monolith_seed4.npz")
    assert mono.meta["seed"] == 4 and mono.meta["curriculum"]["name"] == "one"


def test_lesson_rows_are_read_back_as_the_results(taught, tmp_path):
    _, out = taught
    rows = course.lesson_rows(out)
    assert [(r["learner"], r["after_lesson"], r["tested_lesson"]) for r in rows] == [
        ("educated", "descend", "descend"), ("monolith", "descend", "descend")
    ]  # fmt: skip
    w = CsvWriter(tmp_path / "lessons.csv", course.LESSON_COLUMNS)
    for r in rows:
        w.write(r)
    w.write(dict(rows[0], seed=5, learner="monolith"))  # seed 5: no educated course, dropped
    w.close()
    back = course.results_from_rows(list(csv.DictReader(open(tmp_path / "lessons.csv"))))
    assert [r["seed"] for r in back] == [4]
    for learner in course.LEARNERS:
        (a,), (b,) = back[0][learner], out[learner]
        assert (a["lesson"], a["passed"], a["seconds"]) == (b["lesson"], b["passed"], b["seconds"])
        assert a["retention"] == {k: {m: float(v[m]) for m in course.LESSON_METRICS}
                                  for k, v in b["retention"].items()}  # fmt: skip


@pytest.mark.parametrize("p", [EduParams(), dataclasses.replace(QUICK, seed=7, monolith=False)])
def test_hyper_parameters_are_read_back_from_config_json(p):
    cfg = json.loads(json.dumps({"hyper_parameters": to_jsonable(p)}))
    assert course.params_from_config(cfg) == p
    old = dict(cfg["hyper_parameters"])
    del old["dqfd"], old["measures"]  # a run from before DQfD and the measures objective
    back = course.params_from_config({"hyper_parameters": old})
    assert back.dqfd == EduParams().dqfd and back.measures == EduParams().measures
    with pytest.raises(KeyError):
        course.params_from_config({"hyper_parameters": {"irl_iters": 1}})


def test_evaluation_protocol_on_the_taught_policy(taught):
    job, _ = taught
    pol = load_policy(job.policy_dir / "educated_seed4.npz")
    assert [E.eval_seed(sc) for sc in E.EVAL_SCENARIOS] == [300_000] + [200_000] * 3
    folder = job.policy_dir.parent  # a run folder: policies/*.npz, grouped by learner
    assert {k: [s for s, _ in v] for k, v in E.run_policies(folder).items()} == {
        "educated": ["educated_seed4"], "monolithic_dqn": ["monolith_seed4"]
    }  # fmt: skip
    cmp = E.compare({4: pol}, [folder, folder], 1, 0.97)
    assert list(cmp) == ["educated", f"educated [{folder.name}]", f"monolithic_dqn [{folder.name}]",
                         "expert (ideal)"]  # fmt: skip
    assert [s for s, _ in cmp[f"monolithic_dqn [{folder.name}]"]["composite"]] == [
        "monolith_seed4"
    ] * 2
    for by in cmp.values():
        assert list(by) == list(E.EVAL_SCENARIOS)
        assert all(0 <= m["all_in_view_frac"] <= 1 for lst in by.values() for _, m in lst)
    # the educated policy read back from its file tests as the one taught
    assert cmp[f"educated [{folder.name}]"]["composite"][0][1] == cmp["educated"]["composite"][0][1]
    assert E.best_seed(cmp) == 4
    fid = E.fidelity_totals({4: pol}, 1)
    for r in fid.values():
        assert 0 <= r["action_rate"] <= 1 and r["action_changed"] <= r["n"]
        assert len(r["per_seed"]) == 1


def test_decision_records_are_the_companions_with_no_net(taught):
    job, _ = taught
    pol = load_policy(job.policy_dir / "educated_seed4.npz")
    recs = E.decision_episode(pol, seed=E.COMPOSITE_SEED)
    dt = TaskParams().dt_s
    assert len(recs) > 1 and [r["t"] for r in recs] == [k * dt for k in range(len(recs))]
    for r in recs:
        assert set(KEYS) | {"action", "explanation"} == set(r)
        assert r["verdict"] == "none" and r["reason"] == E.NO_NET and r["mode"] == "ai"
        assert r["proposed"] == r["certified"] == {
            "pos_ned": None, "vel_ned": list(action_velocity_ned(r["action"])), "yaw": 0.0
        }  # fmt: skip
        assert set(r["explanation"]) == {"module", "reason", "concepts"} and len(r["phi"]) == 8
    first = parse_record(recs[0])
    assert first.action and first.net == "none" and first.who == "descend"
    assert timeline([parse_record(r) for r in recs])[0].startswith("t = 0.0 s descend: ")
    assert ACTION_NAMES[recs[0]["action"]] in ("hover", "descend")
    np.testing.assert_array_equal(E.decision_episode(pol)[0]["phi"], recs[0]["phi"])


def _finished_run(folder, out, p, sha="abc"):
    """A run folder as `skyherd educate` leaves it: config.json, lessons.csv, policies/."""
    (folder / "policies").mkdir(parents=True)
    cfg = {"curriculum": {"name": "one", "sha256": sha}, "hyper_parameters": to_jsonable(p)}
    (folder / "config.json").write_text(json.dumps(cfg))
    w = CsvWriter(folder / "lessons.csv", course.LESSON_COLUMNS)
    for r in course.lesson_rows(out):
        w.write(r)
    w.close()
    return folder


def test_finished_runs_are_read_back_as_one(taught, tmp_path):
    _, out = taught
    a = _finished_run(tmp_path / "a", out, QUICK)
    b = _finished_run(tmp_path / "b", dict(out, seed=9), dataclasses.replace(QUICK, monolith=False))
    done = course.read_finished_runs([b, a], "abc")
    assert [r["seed"] for r in done.results] == [4, 9] and done.params.monolith is False
    assert done.policy_dirs == {4: a / "policies", 9: b / "policies"}
    assert done.curriculum == {"name": "one", "sha256": "abc"}
    for folders, sha, words in (
        ([a], "abd", "another curriculum"),
        ([a, a], "abc", "seed 4 is also in another run"),
        ([tmp_path / "none"], "abc", "not a finished educate run"),
    ):
        with pytest.raises(ValueError, match=words):
            course.read_finished_runs(folders, sha)
    other = _finished_run(
        tmp_path / "c", dict(out, seed=5), dataclasses.replace(QUICK, irl_iters=2)
    )
    with pytest.raises(ValueError, match=f"other hyper-parameters than {a}"):
        course.read_finished_runs([a, other], "abc")
