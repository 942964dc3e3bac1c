"""The curriculum file: the default loads; bad files are refused with one line naming the key."""

import re
from pathlib import Path

import numpy as np
import pytest

from skyherd.policy.education.concepts import compile_concepts, decode_observation
from skyherd.policy.education.curriculum import DEFAULT_CURRICULUM, CurriculumError, load_curriculum
from skyherd.scripts.cli import main

TEXT = DEFAULT_CURRICULUM.read_text()


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "c.toml"
    p.write_text(text)
    return p


def _refused(tmp_path, text, *needles):
    with pytest.raises(CurriculumError) as e:
        load_curriculum(_write(tmp_path, text))
    msg = str(e.value)
    assert "\n" not in msg
    for n in needles:
        assert n in msg, msg
    return msg


def test_default_curriculum_loads_in_semantic_order():
    cur = load_curriculum(DEFAULT_CURRICULUM)
    assert cur.name == "groundair" and re.fullmatch(r"\d+\.\d+\.\d+", cur.version)
    assert len(cur.sha256) == 64 and [le.name for le in cur.lessons] == [
        "lateral",
        "climb",
        "descend",
    ]
    assert cur.composite.method == "measures" and set(cur.composite.modules) == {
        "lateral",
        "climb",
        "descend",
    }
    preds = [c for c in cur.concepts.values() if c.kind == "predicate"]
    assert {p.name for p in preds} >= set(cur.composite.arbiter_inputs)
    team_east = cur.concepts["team_east"]
    assert (team_east.quantity, team_east.op, team_east.threshold) == ("aim_east", ">", 0.08)
    # the modules read predicates only (so explanations can cite all a decision depends on)
    assert all(cur.concepts[n].kind == "predicate" for le in cur.lessons for n in le.inputs)


def test_concepts_compute_from_the_observation():
    cur = load_curriculum(DEFAULT_CURRICULUM)
    f = compile_concepts(cur.concept_list())
    obs = np.full(14, 0.5)
    obs[0], obs[2], obs[3] = 0.81, 0.20, 0.5  # team right of centre, tight, 30 m
    obs[11] = 0.5 - 5 * 0.02  # drifting 0.02 west per step
    v = f(obs)
    assert v["offset_east"] == pytest.approx(0.31) and v["altitude"] == pytest.approx(30.0)
    assert v["aim_east"] == pytest.approx(0.31 - 2 * 0.02)  # two steps of look-ahead
    assert v["spread_error"] == pytest.approx(0.20 - 0.35)
    assert cur.concepts["team_east"].holds(v["aim_east"])
    assert cur.concepts["too_tight"].holds(v["spread_aim"])
    assert decode_observation(obs)["vel_n"] == pytest.approx(0.0)


def test_lesson_using_a_concept_taught_later_is_refused(tmp_path):
    bad = TEXT.replace(
        'inputs = ["team_east", "team_west"',
        'inputs = ["too_wide", "team_east", "team_west"',
    )
    msg = _refused(tmp_path, bad, "lesson 'lateral'", "'too_wide'", "taught later", "'climb'")
    assert msg.startswith(str(tmp_path))


def test_arbiter_reading_an_untaught_concept_is_refused(tmp_path):
    bad = TEXT.replace('"mostly_east_west", "off_centre"]', '"mostly_east_west"]')
    _refused(tmp_path, bad, "lesson 'composite'", "'off_centre'", "taught by no lesson")


def test_other_bad_files_are_refused_naming_the_key(tmp_path):
    _refused(tmp_path, TEXT.replace('formula = "com_u - 0.5"', 'formula = "com_uu - 0.5"'),
             "concepts.offset_east.formula", "'com_uu'")  # fmt: skip
    _refused(tmp_path, TEXT.replace('formula = "com_u - 0.5"', 'formula = "__import__(1)"'),
             "concepts.offset_east.formula", "not allowed")  # fmt: skip
    _refused(tmp_path, TEXT.replace('"skyherd-curriculum/1"', '"skyherd-curriculum/9"'), "format")
    _refused(tmp_path, re.sub(r'(?m)^version = ".*"', 'version = "one"', TEXT), "version")
    _refused(tmp_path, re.sub(r'(?m)^warm_start = "demos"', 'warm_start = "guess"', TEXT, count=1),
             "lessons[0] (lateral).warm_start", "'guess'")  # fmt: skip
    _refused(tmp_path, TEXT.replace("retention_weight = 0.0", "retention_weight = -1"),
             "composite.retention_weight", "-1")  # fmt: skip
    _refused(tmp_path, TEXT.replace('pass = {all_in_view_frac = ">= 0.9"}\n\n[[lessons]]\nname = "climb"',
                                    'pass = {all_in_view_frac = "> 0.9"}\n\n[[lessons]]\nname = "climb"'),
             "lessons[0] (lateral).pass.all_in_view_frac")  # fmt: skip
    _refused(
        tmp_path,
        TEXT.replace('method = "irl"', 'method = "magic"', 1),
        "lessons[0] (lateral).method",
    )
    _refused(tmp_path, TEXT.replace('actions = ["hover", "climb"]', 'actions = ["hover", "jump"]'),
             "lessons[1] (climb).actions")  # fmt: skip
    _refused(tmp_path, TEXT.replace('requires = ["lateral"]', 'requires = ["descend"]'),
             "lesson 'climb'.requires", "'descend' is not an earlier lesson")  # fmt: skip
    _refused(tmp_path, TEXT.replace('formula = "aim_east > 0.08"', 'formula = "com_u > 0.58"'),
             "concepts.team_east.formula", "quantity concept")  # fmt: skip
    _refused(
        tmp_path,
        TEXT.replace('module = "climb"', 'module = "lateral"'),
        "module 'lateral' is already taught",
    )
    _refused(tmp_path, "not = [toml", "not TOML")


def test_educate_refuses_a_bad_curriculum_with_exit_2(tmp_path, capsys):
    bad = _write(
        tmp_path,
        TEXT.replace('teaches = ["in_view", "seen"', 'teaches = ["in_view", "sen"'),
    )
    assert main(["educate", str(bad), "--runs-dir", str(tmp_path / "runs")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'sen'" in err[0] and "lesson 'climb'" in err[0]
    assert not (tmp_path / "runs").exists()  # nothing was started
    assert main(["educate", str(tmp_path / "none.toml")]) == 2


def _table(f: dict) -> dict[str, int]:
    """The scripted demonstrator's rule written over the default curriculum's predicates."""
    east_west, north_south = f["team_east"] or f["team_west"], f["team_south"] or f["team_north"]
    if east_west and (f["mostly_east_west"] or not north_south):
        lateral = 3 if f["team_east"] else 4
    else:
        lateral = (2 if f["team_south"] else 1) if north_south else 0
    climb = 5 if (f["someone_out"] or f["too_wide"]) and not f["near_ceiling"] else 0
    descend = 6 if f["too_tight"] and not (f["someone_out"] or f["near_floor"]) else 0
    return {"lateral": lateral, "climb": climb, "descend": descend}


def test_the_modules_predicates_can_express_the_demonstrator():
    """A module reads predicates only; a table over them flies each skill scenario's test
    episodes as the scripted demonstrator does (what the lessons' modules can learn)."""
    from skyherd.policy.demos import ExpertParams, rollout_stats, scripted_expert
    from skyherd.policy.education.teach import concept_features

    cur = load_curriculum(DEFAULT_CURRICULUM)
    feats = concept_features(cur)
    for le in cur.lessons:
        act = lambda o, m=le.module: _table(feats(o))[m]  # noqa: E731
        table = rollout_stats(act, le.scenario, 4, 100_000, 0.97)[1]
        expert = scripted_expert(le.scenario, ExpertParams(), 0)
        expert = rollout_stats(expert, le.scenario, 4, 100_000, 0.97)[1]
        assert table["all_in_view_frac"] == pytest.approx(expert["all_in_view_frac"], abs=0.02)
        assert table["footprint_ratio"] == pytest.approx(expert["footprint_ratio"], rel=0.05)
        assert table["all_in_view_frac"] >= 0.95, le.name
