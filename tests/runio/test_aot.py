"""runio.aot, for each package's kernels (the quadrotor's, the safety net's): without a C
compiler the build fails, it is said once on stderr with the reason, remembered (not tried
again), and numba's JIT runs the kernels."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

NO_COMPILER = """
import importlib, sys
compiled = importlib.import_module(sys.argv[1])
k = compiled.kernels()
print(compiled.ensure_built(), compiled.ensure_built(), type(getattr(k, sys.argv[2])).__name__)
"""


@pytest.mark.parametrize(
    ("module", "kernel", "what"),
    [
        ("skyherd.flight.multirotor.compiled", "level_with_yaw", "the quadrotor's kernels"),
        ("skyherd.safety.compiled", "worst_residual", "the safety net's kernels"),
    ],
)
def test_without_a_c_compiler_it_says_so_once_and_numbas_jit_runs(tmp_path, module, kernel, what):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PATH=str(tmp_path / "no-compiler"))
    out = subprocess.run([sys.executable, "-c", NO_COMPILER, module, kernel], env=env,
                         capture_output=True, text=True, timeout=300, check=True)  # fmt: skip
    assert out.stdout.split() == ["False", "False", "CPUDispatcher"]  # numba's kernels
    said = [ln for ln in out.stderr.splitlines() if "not compiled ahead of time" in ln]
    assert len(said) == 1 and what in said[0] and "compiler" in said[0], out.stderr[-1000:]
    assert len(list((tmp_path / "skyherd_aot").glob("*.failed"))) == 1  # not tried again
