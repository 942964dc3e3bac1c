"""flight.multirotor.compiled: the quadrotor's kernels compiled ahead of time fly as numba's JIT
does, to the bit; a build for other sources or another CPU setting is never loaded; and with the
build there, `skyherd sim`'s warm-up imports no numba at all (issue 31: ~0.5 CPU s of every
simulator process went to importing numba and loading its cache)."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from skyherd.flight.multirotor import MultirotorAutopilot, compiled


@pytest.fixture(scope="module")
def built():
    if not compiled.ensure_built():
        pytest.fail("the kernels did not compile ahead of time (a C compiler is needed)")
    return compiled.kernels()


def _flight(ap: MultirotorAutopilot) -> np.ndarray:
    """Take-off, two repositions, a landing: the work array (state, controller) each step."""
    assert ap.arm().ok and ap.takeoff(8.0).ok
    rows = []
    for k in range(4000):
        if k in (1500, 2500):
            assert ap.reposition(np.array([5.0 * (k // 1000), -3.0, -6.0]), yaw=0.4).ok
        if k == 3200:
            ap.land()
        ap.step()
        rows.append(ap._w.copy())
    return np.array(rows)


def test_compiled_kernels_fly_as_numbas_jit_to_the_bit(built):
    jit = compiled.AOT.jit()
    assert built.control_step_packed is not jit.control_step_packed  # the compiled module's
    a, b = MultirotorAutopilot(seed=5), MultirotorAutopilot(seed=5)
    b._control_step, b._level_with_yaw = jit.control_step_packed, jit.level_with_yaw
    wa, wb = _flight(a), _flight(b)
    assert np.abs(wa[:, 2]).max() > 5.0  # it flew
    assert np.array_equal(wa.view(np.uint64), wb.view(np.uint64))


def test_a_build_for_other_sources_or_settings_is_not_loaded(built, monkeypatch, tmp_path):
    aot = compiled.AOT
    here = aot.stamp()
    monkeypatch.setenv("NUMBA_CPU_NAME", "generic")  # numba's JIT would compile other code
    assert aot.stamp() != here
    monkeypatch.delenv("NUMBA_CPU_NAME")
    changed = tmp_path / "control.py"
    changed.write_bytes(aot.sources[0].read_bytes() + b"\n# changed\n")
    other = dataclasses.replace(aot, sources=(changed, *aot.sources[1:]))
    assert other.stamp() != here
    jit = aot.jit()
    assert other.kernels().control_step_packed is jit.control_step_packed  # numba's, not stale


WARM = """
import sys
from skyherd.flight.airframes_registry import warm_up
warm_up("quadrotor")
print("numba" in sys.modules, "scipy" in sys.modules)
"""


def test_warm_up_with_the_build_imports_no_numba(built):
    out = subprocess.run([sys.executable, "-c", WARM], capture_output=True, text=True,
                         timeout=300, check=True).stdout.split()  # fmt: skip
    assert out == ["False", "False"]  # neither numba (nor the SciPy it checks for BLAS)
