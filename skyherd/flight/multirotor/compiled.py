"""The quadrotor's two kernels that the autopilot calls (control.py's `control_step_packed`, which
holds the mixer and the physics, and quadrotor_kernels.py's `_level_with_yaw`) compiled ahead of
time into one extension module (runio.aot), so that a process flying the built-in quadrotor
(`skyherd sim`) neither imports numba nor starts its compiler to load them (issue 31).

    kernels()        the compiled module's functions when it is built for these sources on
                     this CPU, else numba's dispatchers of the same functions
    ensure_built()   build the module when it is missing (`skyherd sim` calls it at its start,
                     airframes_registry.warm_up, as numba compiled the kernels there before)
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

from skyherd.runio.aot import AotModule

HERE = Path(__file__).resolve().parent
AOT = AotModule(
    prefix="_quad_kernels_",  # the compiled module's name: prefix + stamp
    what="the quadrotor's kernels",
    sources=(
        HERE / "control.py",
        HERE / "layout.py",
        HERE / "mixer.py",
        HERE.parent / "quadrotor.py",
        HERE.parent / "quadrotor_kernels.py",
        Path(__file__),
    ),  # fmt: skip
    exports={  # name in the compiled module → (the njit function, its numba signature)
        "control_step_packed": (
            "skyherd.flight.multirotor.control:control_step_packed",
            "void(float64[::1], float64[::1], float64, int64)",
        ),  # fmt: skip
        "level_with_yaw": (
            "skyherd.flight.quadrotor_kernels:_level_with_yaw",
            "void(float64[::1])",
        ),
    },
    home=HERE / "__pycache__",
    spec=f"{__name__}:AOT",
)


def kernels() -> SimpleNamespace:
    """`control_step_packed(w, k, dt, n)` and `level_with_yaw(x)` (runio.aot.AotModule.kernels)."""
    return AOT.kernels()


def ensure_built(timeout_s: float = 600.0) -> bool:
    """Build the compiled module when it is missing (runio.aot.AotModule.ensure_built)."""
    return AOT.ensure_built(timeout_s)
