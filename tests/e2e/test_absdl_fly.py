"""`skyherd fly --policy` with the kept ABS-DL policy (policy/models/groundair_absdl.npz): the
deep policy flies the ground-air mission end to end (sim + companion over MAVLink and Zenoh,
lockstep), proposes continuous velocity commands, explains each decision by the sub-skill network
that decided and its weight, and the net leaves (almost) all of them as proposed. Run inside
`unshare -n` (loopback only): instance 88, Zenoh port 7488. `check_deep_policy` is the same
record checked on real autopilots through the bridges (tests/e2e/test_absdl_bridges.py)."""

import json
import re
import time
from pathlib import Path

import numpy as np
import pytest

from skyherd.policy.models import ABSDL_POLICY
from skyherd.scripts.cli import main
from skyherd.task.params import N_ACTIONS, action_velocity_ned

MODULES = ("lateral", "climb", "descend")  # the sub-skill networks the fused policy names


def check_deep_policy(run: Path, min_decisions: int = 55) -> dict:
    """The deep policy decided in `run` (a `skyherd fly` run folder): its decisions, continuous
    commands, each explained by the sub-skill network that decided and its weight. Returns the
    figures: all-in-view fraction, share of decisions the net changed, networks used, switches
    between them."""
    summary = (run / "summary.md").read_text()
    in_view = float(
        re.search(r"all UGVs in view \[fraction of decisions\] \| ([0-9.]+)", summary)[1]
    )
    rows = [json.loads(x) for x in (run / "decisions.jsonl").read_text().splitlines()]
    ours = [r for r in rows if r["pilot"] == "policy"]
    assert len(ours) >= min_decisions, len(ours)
    changed = [r for r in ours if r["verdict"] != "accepted"]
    rows_discrete = {tuple(action_velocity_ned(a)) for a in range(N_ACTIONS)}
    proposed = [tuple(r["proposed"]["vel_ned"]) for r in ours]
    assert sum(p not in rows_discrete for p in proposed) > len(ours) // 2  # continuous commands
    modules = []
    for r in ours:
        why = r["explanation"]
        assert why["module"] in MODULES
        assert 0.0 <= why["weight"] <= 1.0 and 0.0 <= why["share"] <= 1.0
        assert np.allclose(why["command_ned_mps"], r["proposed"]["vel_ned"])
        assert why["module"] in why["reason"]
        modules.append(why["module"])
    fig = {
        "in_view": in_view,
        "decisions": len(ours),
        "changed_by_net": round(len(changed) / len(ours), 3),
        "changed_reasons": sorted({r["reason"] for r in changed}),
        "modules": {m: modules.count(m) for m in MODULES},
        "module_switches": sum(a != b for a, b in zip(modules, modules[1:], strict=False)),
    }
    print("deep policy:", json.dumps(fig))
    assert "lateral" in modules and len(set(modules)) >= 2, fig  # the fusion at work
    return fig


@pytest.mark.slow
def test_fly_the_deep_policy(tmp_path, capsys):
    args = ["fly", "--policy", str(ABSDL_POLICY), "--duration", "30", "--speedup", "0",
            "--timeout", "600", "--instance", "88", "--zenoh-port", "7488",
            "--runs-dir", str(tmp_path)]  # fmt: skip
    wall = time.monotonic()
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    with capsys.disabled():
        print("built-in: wall time [s]", round(time.monotonic() - wall, 1))
        fig = check_deep_policy(run)  # one decision every 0.5 s for 30 s
    assert fig["in_view"] >= 0.9, (run / "summary.md").read_text()
    assert fig["changed_by_net"] < 0.10, fig["changed_reasons"]
