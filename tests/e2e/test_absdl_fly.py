"""`skyherd fly --policy` with the kept ABS-DL policy (policy/models/groundair_absdl.npz): the
deep policy flies the ground-air mission end to end (sim + companion over MAVLink and Zenoh,
lockstep), proposes continuous velocity commands, explains each decision by the sub-skill network
that decided and its weight, and the net leaves (almost) all of them as proposed. Run inside
`unshare -n` (loopback only): instance 88, Zenoh port 7488."""

import json
import re

import numpy as np

from skyherd.policy.models import ABSDL_POLICY
from skyherd.scripts.cli import main
from skyherd.task.params import N_ACTIONS, action_velocity_ned


def test_fly_the_deep_policy(tmp_path, capsys):
    args = ["fly", "--policy", str(ABSDL_POLICY), "--duration", "30", "--speedup", "0",
            "--timeout", "600", "--instance", "88", "--zenoh-port", "7488",
            "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    summary = (run / "summary.md").read_text()
    frac = float(re.search(r"all UGVs in view \[fraction of decisions\] \| ([0-9.]+)", summary)[1])
    assert frac >= 0.9, summary
    rows = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    ours = [r for r in rows if r["pilot"] == "policy"]
    assert len(ours) >= 55  # one every 0.5 s for 30 s
    changed = sum(r["verdict"] != "accepted" for r in ours)
    assert changed / len(ours) < 0.10, [r["reason"] for r in ours if r["verdict"] != "accepted"]
    rows_discrete = {tuple(action_velocity_ned(a)) for a in range(N_ACTIONS)}
    proposed = [tuple(r["proposed"]["vel_ned"]) for r in ours]
    assert sum(p not in rows_discrete for p in proposed) > len(ours) // 2  # continuous commands
    modules = set()
    for r in ours:
        why = r["explanation"]
        assert why["module"] in ("lateral", "climb", "descend")
        assert 0.0 <= why["weight"] <= 1.0 and 0.0 <= why["share"] <= 1.0
        assert np.allclose(why["command_ned_mps"], r["proposed"]["vel_ned"])
        assert why["module"] in why["reason"]
        modules.add(why["module"])
    assert "lateral" in modules and len(modules) >= 2, modules  # the fusion at work
