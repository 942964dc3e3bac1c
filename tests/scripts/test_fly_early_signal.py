"""A signal to `skyherd fly` after the command line is parsed and before its run folder is made:
exit 128 + signum, "nothing was recorded" said, no run folder. The window lies between
scripts/cli.main putting the usual handlers back and the flight's start; a full run once hit it
at load 3 (test_ctrl_c_at_any_moment[0.4]: cli's generic "INTERRUPTED" without "nothing was").
Here the signal is sent by the process to itself inside that window, at a chosen point, so the
moment does not depend on the machine's load. No child starts and nothing listens: no network."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

RIG = r"""
import json, os, signal, sys, time
from skyherd.scripts import cli, fly, fly_formation

spec = json.loads(sys.argv[1])
where = spec["where"]
sig = getattr(signal, spec["signal"])

def hit(f, wait_s=0.0):
    def hit_then(*a, **k):
        os.kill(os.getpid(), sig)
        time.sleep(wait_s)  # a signal raised at once cuts this short
        return f(*a, **k)
    return hit_then

if where == "checks":
    fly._check_own = hit(fly._check_own)
elif where == "validate":
    fly._validate = hit(fly._validate)
elif where == "formation-checks":
    fly_formation._check = hit(fly_formation._check)
elif where == "formation-plan":
    fly_formation.obtain_plan = hit(fly_formation.obtain_plan, wait_s=30.0)
t0 = time.monotonic()
rc = cli.main(["fly", "--runs-dir", spec["runs"], *spec["fly"]])
print(json.dumps({"rc": rc, "wall_s": time.monotonic() - t0}))
"""

FORMATION = ["--mission", "formation", "--agents", "4", "--instance", "150"]


@pytest.mark.parametrize(
    "where,sig,rc,fly",
    [
        ("checks", "SIGINT", 130, ["--instance", "150"]),
        ("validate", "SIGTERM", 143, ["--instance", "150"]),
        ("formation-checks", "SIGINT", 130, FORMATION),
        ("formation-plan", "SIGHUP", 129, FORMATION),
    ],
)
def test_a_signal_before_the_run_folder_says_nothing_was_recorded(tmp_path, where, sig, rc, fly):
    runs = tmp_path / "runs"
    spec = {"where": where, "signal": sig, "runs": str(runs), "fly": fly}
    p = subprocess.run([sys.executable, "-c", RIG, json.dumps(spec)], capture_output=True,
                       text=True, timeout=120)  # fmt: skip
    said = p.stdout + p.stderr
    assert p.returncode == 0, said[-3000:]
    res = json.loads(p.stdout.strip().splitlines()[-1])
    assert res["rc"] == rc, said[-3000:]
    assert "INTERRUPTED: interrupted (" in said and "nothing was recorded" in said, said[-3000:]
    assert "Traceback" not in said, said[-3000:]
    assert not runs.exists() or not any(runs.iterdir()), list(runs.iterdir())
    if where == "formation-plan":  # a plan being learned is stopped at once, not after it
        assert res["wall_s"] < 25.0, res
