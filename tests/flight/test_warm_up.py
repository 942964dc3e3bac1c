"""flight.airframes_registry.warm_up: after it, a new autopilot's first step compiles nothing.

On a fresh installation (numba's cache empty) the quadrotor's first step compiled its physics
and controller, about 3.5 s of CPU; `skyherd sim` stepped it inside the first lockstep tick,
where the companion's 60 s wall-clock patience runs, and a first flight under load aborted.
`skyherd sim` now warms the airframe up before its vehicle answers anyone (world.serve).
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

FIRST_STEP = """
import sys, time
from skyherd.flight.airframes_registry import make_autopilot, warm_up
if sys.argv[1] == "warm":
    warm_up("quadrotor")
c = time.process_time()
make_autopilot("quadrotor", seed=3).step()
print(time.process_time() - c)
"""


def _first_step_cpu_s(cache_dir, warm: bool) -> float:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir))
    out = subprocess.run([sys.executable, "-c", FIRST_STEP, "warm" if warm else "cold"],
                         env=env, capture_output=True, text=True, timeout=600, check=True)  # fmt: skip
    return float(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_after_warm_up_the_first_step_of_a_fresh_installation_compiles_nothing(tmp_path):
    cold = _first_step_cpu_s(tmp_path / "cold", warm=False)  # an empty cache: it compiles
    warmed = _first_step_cpu_s(tmp_path / "warm", warm=True)  # an empty cache, warmed up first
    assert cold > 1.0  # CPU time: the compilation, whatever the machine's load
    assert warmed < 0.1 * cold, (warmed, cold)
