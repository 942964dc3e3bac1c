"""The safety net's kernels (kernels.py: the union-of-polyhedra test, the selected polyhedron,
the nearly-active row) compiled ahead of time into one extension module (runio.aot), so that
the companion neither imports numba nor loads numba's cache to run them (~0.45 CPU s of every
companion's start, issue 31). The net's warm-up builds the module when it is missing
(safety.net.warm_up); until then, and wherever it cannot be built, numba's JIT runs them.

    kernels()        worst_residual, select_mask, nearest_active: the compiled module's for
                     these sources on this CPU, else numba's dispatchers (looked up once per
                     process, again after a build)
    ensure_built()   build the module when it is missing

The arguments are the envelope's arrays (safety.envelope.Envelope: A (m, NZ), b, near float64,
piece_starts and zone_starts intp) and a state z (NZ,) or residuals r (m,) float64; the
compiled module takes any strides but converts no dtype (runio.aot).
"""

from __future__ import annotations

import functools
from pathlib import Path
from types import SimpleNamespace

from skyherd.runio.aot import AotModule

HERE = Path(__file__).resolve().parent
_A, _V, _I = "float64[:, :]", "float64[:]", "intp[:]"
AOT = AotModule(
    prefix="_safety_kernels_",
    what="the safety net's kernels",
    sources=(HERE / "kernels.py", Path(__file__)),
    exports={  # name in the compiled module → (the njit function, its numba signature)
        "worst_residual": (
            "skyherd.safety.kernels:worst_residual",
            f"float64({_A}, {_V}, {_V}, int64, int64, {_I}, {_I})",
        ),
        "select_mask": (
            "skyherd.safety.kernels:select_mask",
            f"boolean[::1]({_V}, int64, int64, {_I}, {_I})",
        ),
        "nearest_active": (
            "skyherd.safety.kernels:nearest_active",
            f"int64({_A}, {_V}, {_V}, {_V}, int64, int64, {_I}, {_I})",
        ),
    },  # fmt: skip
    home=HERE / "__pycache__",
    spec=f"{__name__}:AOT",
)


@functools.cache
def kernels() -> SimpleNamespace:
    """`worst_residual`, `select_mask`, `nearest_active` (runio.aot.AotModule.kernels)."""
    return AOT.kernels()


def ensure_built(timeout_s: float = 600.0) -> bool:
    """Build the compiled module when it is missing (runio.aot.AotModule.ensure_built); the
    build is what kernels() returns from then on in this process — also one that another
    process made after this one first asked for the kernels (a test suite's second worker, a
    second companion), which this process then finds already built."""
    ok = AOT.ensure_built(timeout_s)
    if ok:
        kernels.cache_clear()
    return ok
