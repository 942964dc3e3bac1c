"""A two-lesson curriculum learnt end to end with a tiny budget; the modular policy file loads
wherever the AB policy loads (load_policy, the gymnasium env, `skyherd fly`'s loader), explains
every decision consistently with the action it takes, and bad files are refused."""

import csv
import json

import numpy as np
import pytest

from skyherd.policy.dqn import MLPPolicy, PolicyFileError, load_policy
from skyherd.policy.education.curriculum import load_curriculum
from skyherd.policy.education.modular import Arbiter, ModularPolicy, SkillModule
from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.scripts.cli import main
from skyherd.task.params import ACTION_NAMES, action_velocity_ned

TWO = """
format = "skyherd-curriculum/1"
name = "two"
version = "0.1"
[concepts.spread_error]
formula = "spread - SPREAD_TARGET"
unit = "image half-diagonal"
[concepts.in_view]
formula = "all_in_view"
unit = "-"
[concepts.too_wide]
formula = "spread_error > 0.06"
unit = "bool"
text = "team spread {value:.2f} over target"
[concepts.someone_out]
formula = "in_view < 0.5"
unit = "bool"
[concepts.too_tight]
formula = "spread_error < -0.06"
unit = "bool"

[[lessons]]
name = "climb"
scenario = "climb"
teaches = ["spread_error", "in_view", "too_wide", "someone_out"]
module = "climb"
inputs = ["spread_error", "in_view"]
actions = ["hover", "climb"]
method = "irl"
warm_start = "demos"
pass = {all_in_view_frac = ">= 0.5"}

[[lessons]]
name = "descend"
scenario = "descend"
teaches = ["too_tight"]
module = "descend"
inputs = ["spread_error"]
actions = ["hover", "descend"]
method = "dqn"
reward = {all_in_view = 1.0, spread_30_45 = 0.5}
pass = {footprint_ratio = "<= 30"}
requires = ["climb"]

[composite]
scenario = "composite"
method = "reward"
reward = {all_in_view = 1.0, spread_30_45 = 0.4}
retention_weight = 0.5
arbiter_inputs = ["someone_out", "too_wide", "too_tight"]
modules = ["climb", "descend"]
requires = ["climb", "descend"]
"""


def _check_explanations(pol, scenario="composite", seed=0):
    env = GroundAirEnv(scenario)
    obs, _ = env.reset(seed=seed)
    for _ in range(40):
        a = pol(obs)
        ex = pol.explain(obs)
        assert ex["action"] == ACTION_NAMES[a]
        mod = pol.modules[ex["module"]]
        assert a in mod.actions and ex["reason"]
        # the values behind every concept the module reads are recorded
        behind = {pol.concepts[n].quantity or n for n in mod.inputs}
        assert behind <= set(ex["concepts"])
        # a cited predicate changes the action when crossed; one on an uncited quantity not
        vals = pol.values(obs)
        for c in pol.preds:
            n = c.name
            v2 = dict(vals, **{c.quantity: c.across(vals[c.quantity], 1e-6)})
            changed = pol.decide(v2)[2] != a
            if n in ex["cited"]:
                assert changed
            elif not any(pol.concepts[x].quantity == c.quantity for x in ex["cited"]):
                assert not changed  # nothing cited on this quantity: crossing it changes nothing
        holds = pol.holds(pol.values(obs))
        fired = [p for p, m in pol.arbiter.rules if holds[p]]
        assert ex["module"] == (dict(pol.arbiter.rules)[fired[0]] if fired else pol.arbiter.default)
        obs, *_ = env.step(a)


@pytest.mark.slow
def test_two_lesson_curriculum_end_to_end(tmp_path, capsys):
    cur = tmp_path / "two.toml"
    cur.write_text(TWO)
    runs = tmp_path / "runs"
    saved = tmp_path / "edu.npz"
    args = ["educate", str(cur), "--quick", "--seeds", "1", "--eval-episodes", "1",
            "--runs-dir", str(runs), "--save-policy", str(saved)]  # fmt: skip
    assert main(args) == 0
    (run,) = list(runs.iterdir())
    for name in ("config.json", "lessons.csv", "events.jsonl", "summary.md", "lessons.png",
                 "compare.png", "results.json", "decisions.jsonl", "policies/educated_seed0.npz",
                 "policies/monolith_seed0.npz"):  # fmt: skip
        assert (run / name).exists(), name
    cfg = json.loads((run / "config.json").read_text())
    sha = load_curriculum(cur).sha256
    assert (
        cfg["curriculum"]["sha256"] == sha and cfg["hyper_parameters"]["dqn"]["total_steps"] == 400
    )
    rows = list(csv.DictReader(open(run / "lessons.csv")))
    # educated: after climb 1 test, after descend 2, after composite 3; the monolith the same
    assert len(rows) == 2 * (1 + 2 + 3)
    assert {r["after_lesson"] for r in rows} == {"climb", "descend", "composite"}
    summary = (run / "summary.md").read_text()
    assert "Retention" in summary and "Explanation fidelity" in summary and "t = 0.0 s" in summary

    pol = load_policy(saved)  # the loader `skyherd fly` uses
    assert isinstance(pol, ModularPolicy)
    assert pol.meta["curriculum"]["sha256"] == sha and pol.meta["curriculum"]["version"] == "0.1"
    assert set(pol.modules) == {"climb", "descend"}
    _check_explanations(pol)
    # the evaluation's decision records agree with the action each one took
    for line in (run / "decisions.jsonl").read_text().splitlines():
        rec = json.loads(line)
        ex = rec["explanation"]
        assert set(ex) == {"module", "reason", "concepts"}
        assert ACTION_NAMES.index(ex_action(rec)) in pol.modules[ex["module"]].actions
        assert rec["proposed"]["vel_ned"] == list(action_velocity_ned(rec["action"]))
    # and `skyherd explain` reads them
    capsys.readouterr()
    assert main(["explain", str(run)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("t = 0.0 s ") and "decisions," in out
    # the report alone, again, from the run's lessons.csv and policies
    again = [
        "educate",
        str(cur),
        "--from-run",
        str(run),
        "--eval-episodes",
        "1",
        "--runs-dir",
        str(runs),
    ]
    assert main(again) == 0
    (other,) = [d for d in runs.iterdir() if d != run]
    assert json.loads((other / "config.json").read_text())["from_run"] == str(run)
    assert (other / "summary.md").read_text().split("## Lesson by lesson")[1].split("## Unseen")[
        0
    ] == (summary.split("## Lesson by lesson")[1].split("## Unseen")[0])
    assert main(again + ["--from-run", str(run)]) == 2  # the same seed twice: refused
    cur.write_text(TWO.replace('version = "0.1"', 'version = "0.2"'))
    assert main(again) == 2  # another curriculum: refused


@pytest.mark.slow
def test_educate_is_deterministic_for_a_seed(tmp_path):
    """Two runs of one small curriculum with one seed give identical weights, the educated
    policy's and the monolithic DQN's, and identical lesson tables (docs/education.md)."""
    cur = tmp_path / "two.toml"
    cur.write_text(TWO)
    runs = []
    for name in ("a", "b"):
        out = tmp_path / name
        args = ["educate", str(cur), "--quick", "--seeds", "1", "--seed", "2", "--eval-episodes",
                "1", "--runs-dir", str(out)]  # fmt: skip
        assert main(args) == 0
        (run,) = out.iterdir()
        runs.append(run)
    for pol in ("educated_seed2.npz", "monolith_seed2.npz"):
        with np.load(runs[0] / "policies" / pol) as a, np.load(runs[1] / "policies" / pol) as b:
            assert a.files == b.files
            for k in a.files:
                np.testing.assert_array_equal(a[k], b[k], err_msg=f"{pol} {k}")
    rows = [list(csv.DictReader(open(r / "lessons.csv"))) for r in runs]
    drop = lambda rs: [{k: v for k, v in r.items() if "cpu" not in k and "_s" not in k} for r in rs]  # noqa: E731
    assert drop(rows[0]) == drop(rows[1])


def ex_action(rec):
    return ACTION_NAMES[rec["action"]]


def _tiny_policy(rng) -> ModularPolicy:
    cur = load_curriculum(
        __import__("skyherd.policy.education.curriculum", fromlist=["x"]).DEFAULT_CURRICULUM
    )
    lat = cur.lesson("lateral")
    n_lat, n_up = len(lat.inputs), len(cur.lesson("climb").inputs)
    net = MLPPolicy(
        [rng.normal(size=(8, n_lat)), rng.normal(size=(5, 8))], [np.zeros(8), np.zeros(5)], {}
    )
    up = MLPPolicy([rng.normal(size=(2, n_up))], [np.array([0.0, 1.0])], {})
    mods = [SkillModule("lateral", "lateral", lat.inputs, lat.actions, net),
            SkillModule("climb", "climb", cur.lesson("climb").inputs, (0, 5), up)]  # fmt: skip
    arb = Arbiter((("someone_out", "climb"), ("team_east", "lateral")), "climb")
    return ModularPolicy(cur.concept_list(), mods, arb, {"curriculum": {"sha256": cur.sha256}})


def test_modular_file_roundtrip_and_the_fly_loader(tmp_path):
    pol = _tiny_policy(np.random.default_rng(0))
    path = pol.save(tmp_path / "m.npz")
    back = load_policy(path)
    env = GroundAirEnv("composite")
    obs, _ = env.reset(seed=3)
    for _ in range(30):
        assert back(obs) == pol(obs) and back.explain(obs) == pol.explain(obs)
        obs, *_ = env.step(back(obs))
    _check_explanations(back)
    # a UGV out of view: the first rule fires and its reason says so
    o = np.full(14, 0.5, np.float32)
    o[5] = 0.0
    ex = back.explain(o)
    assert ex["module"] == "climb" and "out of view" in ex["reason"]
    # …but the default is climb too: the rule is not decisive, and the explanation says so
    assert "someone_out" not in ex["cited"] and "not decisive" in ex["reason"]
    assert ex["read"] == []
    # `skyherd fly --policy FILE` loads it with the companion's loader; its pilot explains
    from skyherd.flight.state import VehicleState
    from skyherd.mission.build import load_pilot_policy
    from skyherd.mission.pilots import Observation, PolicyPilot
    from skyherd.task.params import TaskParams

    flown = load_pilot_policy(str(path))
    assert isinstance(flown, ModularPolicy)
    state = VehicleState(0.0, np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3),
                         np.array([0, 0, -9.81]), False)  # fmt: skip
    prop = PolicyPilot(flown, TaskParams()).propose(Observation(0.0, state, obs[:8], obs, 0.5))
    assert prop.explanation == flown.explain(obs) and prop.action == flown(obs)
    assert np.allclose(prop.setpoint.vel_ned, action_velocity_ned(prop.action))


def test_bad_modular_files_are_refused(tmp_path):
    pol = _tiny_policy(np.random.default_rng(1))
    path = pol.save(tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"]))
    meta["concepts"][0]["formula"] = "__import__('os').system('true')"
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "evil.npz", **arrays)
    with pytest.raises(PolicyFileError, match="not allowed"):
        load_policy(tmp_path / "evil.npz")
    meta = json.loads(str(np.load(path)["meta"]))
    meta["arbiter"]["default"] = "teleport"
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(PolicyFileError, match="teleport"):
        load_policy(tmp_path / "bad.npz")
    (tmp_path / "cut.npz").write_bytes(path.read_bytes()[:300])
    with pytest.raises(PolicyFileError):
        load_policy(tmp_path / "cut.npz")
