"""`skyherd fly --mission shepherd`: the UAV herds the flock (`--ugvs flock`, groundsim.flock)
behind the ground-air SafetyNet, end to end (sim + companion over loopback, lockstep). Run inside
a private network namespace (instances 70-71, Zenoh 7470-7471)."""

import csv
import json

import numpy as np
import pytest

from skyherd.policy.shepherd.episode import run_episode
from skyherd.policy.shepherd.selector import StrombomSelector
from skyherd.scripts.cli import main


@pytest.mark.slow
def test_fly_shepherd_brings_the_flock_to_the_goal(tmp_path, capsys):
    args = ["fly", "--mission", "shepherd", "--shepherd-selector", "strombom", "--duration", "300",
            "--speedup", "0", "--timeout", "900", "--instance", "70", "--zenoh-port", "7470",
            "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    files = {p.name for p in run.iterdir()}
    assert {"shepherd.png", "shepherd.json", "world.csv", "decisions.jsonl", "summary.md"} <= files
    m = json.loads((run / "shepherd.json").read_text())
    assert m["success"] and m["agents"] == 10 and m["selector"] == "strombom"
    # the flown shepherd does what the point shepherd of the study does on this seed, within
    # the quadrotor's lag: the same time to goal to within 25 %
    study = run_episode(0, StrombomSelector()).time_to_goal_s
    assert abs(m["time_to_goal_s"] - study) < 0.25 * study
    assert m["spread_end_m"] < m["spread_start_m"]
    # it flew behind the net: every shepherd decision certified, and the net left them as they were
    rows = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    skills = [r for r in rows if (r.get("explanation") or {}).get("module") in ("collect", "drive")]
    assert len(skills) > 100 and {r["explanation"]["module"] for r in skills} == {
        "collect",
        "drive",
    }
    assert m["net_changed_fraction"] < 0.1
    # the UAV stayed in the envelope's band while herding (12 m above home)
    world = list(csv.DictReader(open(run / "world.csv")))
    alt = np.array(
        [
            -float(r["down"])
            for r in world
            if r["team_t"] and float(r["team_t"]) < m["time_to_goal_s"]
        ]
    )
    assert 10.5 < alt.min() and alt.max() < 13.5


def test_fly_shepherd_bad_usage_exits_2(tmp_path, capsys):
    base = ["--runs-dir", str(tmp_path), "--instance", "71", "--zenoh-port", "7471"]
    assert main(["fly", "--mission", "shepherd", "--ugvs", "groundsim:route", *base]) == 2
    assert main(["fly", "--ugvs", "flock", *base]) == 2
    assert main(["fly", "--mission", "shepherd", "--connect", "udpin:127.0.0.1:14640", *base]) == 2
    assert "flock" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())
