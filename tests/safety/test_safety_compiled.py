"""safety.compiled: the safety net's kernels compiled ahead of time (runio.aot) answer as numba's
JIT does, to the bit, on the envelopes the net flies and on a union of pieces and zones; a
failed build is said once and numba's JIT answers; and with the build there, the companion's
net starts without numba (issue 31: ~0.45 CPU s of every companion's start went to importing
numba and loading its cache)."""

from __future__ import annotations

import dataclasses
import os
import subprocess
import sys

import numpy as np
import pytest

from skyherd.safety import compiled
from skyherd.safety.config import GUARD_KEYS, default_envelope_path, load_envelope, parse_envelope
from skyherd.safety.envelope import NZ, build
from skyherd.safety.envelope import P as POS

L_SHAPE = [[0, 0], [60, 0], [60, 20], [20, 20], [20, 60], [0, 60]]


@pytest.fixture(scope="module")
def built():
    if not compiled.ensure_built():
        pytest.fail("the safety kernels did not compile ahead of time (a C compiler is needed)")
    return compiled.kernels()


def _envelopes():
    union = {
        "envelope": {"name": "l", "version": "t1", "airframe": "quadrotor"},
        "guards": dict.fromkeys(GUARD_KEYS, "off"),
        "fence": {
            "inclusion": [{"name": "L", "points_ne": L_SHAPE}],
            "exclusion": [{"name": "c", "center_ne": [10, 10], "radius_m": 3}],
        },
    }
    out = [build(parse_envelope(union), predictive=True)]
    for airframe in ("quadrotor", "fixedwing"):
        spec, _ = load_envelope(default_envelope_path(airframe))
        out += [spec.envelope(), spec.geometry()]
    return out


def _args(e, z):
    return (e.A, e.b, z, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)


def test_compiled_kernels_answer_as_numbas_jit_to_the_bit(built):
    jit = compiled.AOT.jit()
    assert type(built.worst_residual) is not type(jit.worst_residual)  # the compiled module's
    rng = np.random.default_rng(7)
    for e in _envelopes():
        seen = set()
        for k in range(2000):
            z = np.zeros(NZ)
            z[POS] = (*rng.uniform(-30, 90, 2), -rng.uniform(-5, 130))
            z[3:] = rng.normal(0, 6, NZ - 3)
            if k % 97 == 0:
                z[rng.integers(NZ)] = np.nan  # not finite: NaN from both
            w = built.worst_residual(*_args(e, z))
            assert np.float64(w).view(np.uint64) == np.float64(
                jit.worst_residual(*_args(e, z))
            ).view(np.uint64)
            i = built.nearest_active(e.A, e.b, z, e.near, *_args(e, z)[3:])
            assert i == jit.nearest_active(e.A, e.b, z, e.near, *_args(e, z)[3:])
            r = e.A @ z - e.b
            m = built.select_mask(r, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
            assert np.array_equal(
                m, jit.select_mask(r, e.n_base, e.n_piece_end, e.piece_starts, e.zone_starts)
            )
            seen.add((w <= 0, i >= 0))
        assert len(seen) >= 2  # inside and outside both met
    # any strides (an argument the compiled module cannot copy is read as it lies)
    e = _envelopes()[0]
    wide = np.zeros((NZ, 2))
    wide[:, 0] = [5.0, 5.0, -10.0, 1.0, 0.5, 0.0, 0.1, 0.0, 2.0, 0.0, 0.0]
    z = wide[:, 0]
    assert not z.flags.c_contiguous
    assert built.worst_residual(*_args(e, z)) == jit.worst_residual(*_args(e, z.copy()))


def test_a_build_for_other_sources_is_not_loaded(built, tmp_path):
    changed = tmp_path / "kernels.py"
    changed.write_bytes(compiled.AOT.sources[0].read_bytes() + b"\n# changed\n")
    other = dataclasses.replace(compiled.AOT, sources=(changed, *compiled.AOT.sources[1:]))
    assert other.stamp() != compiled.AOT.stamp()
    assert other.kernels().worst_residual is compiled.AOT.jit().worst_residual  # numba's


RACE = """
import subprocess, sys
from skyherd.safety import compiled
before = compiled.kernels().worst_residual  # nothing built yet in this cache folder: numba's
name = compiled.AOT.prefix + compiled.AOT.stamp()
subprocess.run([sys.executable, "-m", "skyherd.runio.aot", compiled.AOT.spec, name], check=True)
assert compiled.AOT.is_built()  # another process built it meanwhile
print(compiled.ensure_built(), type(before) is type(compiled.kernels().worst_residual))
"""


def test_a_build_made_by_another_process_is_taken_up(tmp_path):
    """Issue 31 stop 41: a suite's process had asked for the kernels (numba's, nothing built),
    another process then built them, and ensure_built kept handing out numba's (the full suite
    failed test_compiled_kernels_answer_as_numbas_jit_to_the_bit once)."""
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", RACE], capture_output=True, text=True,
                         timeout=600, env=env)  # fmt: skip
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ["True", "False"]  # built, and now the compiled module's


START = """
import sys
from skyherd.mission.build import MissionChoice, build_mission
build_mission(MissionChoice(), None)
print("numba" in sys.modules, "osqp" in sys.modules, "scipy" in sys.modules)
"""


def test_the_companions_net_starts_without_numba_osqp_or_scipy(built):
    """The warm-up runs the net through AI, FALLBACK and PID: its kernels compiled ahead of time
    (no numba), the projection and the recovery target exact (safety.nearest: no OSQP, no SciPy)."""
    out = subprocess.run([sys.executable, "-c", START], capture_output=True, text=True,
                         timeout=300, check=True).stdout.split()  # fmt: skip
    assert out == ["False", "False", "False"]
