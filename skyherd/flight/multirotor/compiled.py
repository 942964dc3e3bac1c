"""The quadrotor's two kernels that the autopilot calls (control.py's `control_step_packed`, which
holds the mixer and the physics, and quadrotor_kernels.py's `_level_with_yaw`) compiled ahead of
time into one extension module, so that a process flying the built-in quadrotor (`skyherd sim`)
neither imports numba nor starts its compiler to load them from numba's cache: that (numba's
import, its target registries, SciPy imported for its BLAS check, the cached objects) cost
~0.5 CPU s in every simulator process (issue 31).

    kernels()        the compiled module's functions when it is built for these sources on
                     this CPU, else numba's dispatchers of the same functions
    ensure_built()   build the module when it is missing: numba.pycc in a child process, ~5 CPU s
                     once per change of the kernels' sources (`skyherd sim` calls it at its start,
                     airframes_registry.warm_up, as numba compiled the kernels there before)

The module's file name carries a stamp of everything its machine code depends on (the kernels'
source files and those of the constants they read, this file, numba's and llvmlite's versions,
the CPU, numba's environment, Python's version), so a stale build is never loaded. numba's
ahead-of-time compiler is given the host CPU's name and features, as its JIT has them: the same
instructions, the same rounding, and the same flight to the byte as the JIT's kernels
(docs/topology.md's hashes). A build that fails (no C compiler) is said once on stderr and
remembered beside it (`<name>.failed`: delete it to try again); the kernels are then numba's JIT,
as before.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace

HERE = Path(__file__).resolve().parent
SOURCES = (HERE / "control.py", HERE / "layout.py", HERE / "mixer.py", HERE.parent / "quadrotor.py",
           HERE.parent / "quadrotor_kernels.py", Path(__file__))  # fmt: skip
PREFIX = "_quad_kernels_"  # the compiled module's name: PREFIX + stamp
EXPORTS = {  # name in the compiled module → numba signature
    "control_step_packed": "void(float64[::1], float64[::1], float64, int64)",
    "level_with_yaw": "void(float64[::1])",
}


def _version_file(package: str) -> bytes:
    """`package`'s _version.py (its version), found without importing the package."""
    spec = importlib.util.find_spec(package)
    if spec is None or spec.origin is None:
        return b""
    try:
        return (Path(spec.origin).parent / "_version.py").read_bytes()
    except OSError:
        return b""


def _cpu() -> bytes:
    """What the CPU offers (its model and flags, as the kernel reports them)."""
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        import platform

        return platform.processor().encode() + platform.machine().encode()
    keep = ("model name", "flags", "vendor_id", "cpu family", "model\t")
    return "\n".join(dict.fromkeys(ln for ln in text.splitlines() if ln.startswith(keep))).encode()


def stamp() -> str:
    """The stamp of the kernels' machine code (module docstring)."""
    h = hashlib.sha256()
    for p in SOURCES:
        h.update(p.read_bytes())
    h.update(_version_file("numba") + _version_file("llvmlite") + _cpu())
    numba_env = sorted((k, v) for k, v in os.environ.items() if k.startswith("NUMBA_"))
    h.update(repr([kv for kv in numba_env if kv[0] != "NUMBA_CACHE_DIR"]).encode())
    h.update(sys.version.encode())
    return h.hexdigest()[:16]


def cache_dir() -> Path:
    """Where the compiled module lives: under $NUMBA_CACHE_DIR when it is set, else beside the
    sources' other caches (numba's own choice, __pycache__)."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return Path(os.environ["NUMBA_CACHE_DIR"]) / "skyherd_aot"
    return HERE / "__pycache__"


def _built(name: str) -> Path | None:
    found = sorted(cache_dir().glob(f"{name}.*.so")) + sorted(cache_dir().glob(f"{name}.*.pyd"))
    return found[0] if found else None


def _jit() -> SimpleNamespace:
    from skyherd.flight.multirotor.control import control_step_packed
    from skyherd.flight.quadrotor_kernels import _level_with_yaw

    return SimpleNamespace(control_step_packed=control_step_packed, level_with_yaw=_level_with_yaw)


def kernels() -> SimpleNamespace:
    """`control_step_packed(w, k, dt, n)` and `level_with_yaw(x)`: the compiled module's when
    it is built for this stamp, else numba's (NUMBA_DISABLE_JIT: always numba's, in Python)."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return _jit()
    name = PREFIX + stamp()
    path = _built(name)
    if path is None:
        return _jit()
    spec = importlib.util.spec_from_file_location(name, path)
    try:
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
    except (ImportError, OSError):  # replaced meanwhile by another build: numba's kernels
        return _jit()
    return SimpleNamespace(**{k: getattr(module, k) for k in EXPORTS})


def ensure_built(timeout_s: float = 600.0) -> bool:
    """Build the compiled module for this stamp when it is missing (a child process; its
    failure is said once on stderr and remembered beside it). True when it is there."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    name = PREFIX + stamp()
    if _built(name) is not None:
        return True
    failed = cache_dir() / f"{name}.failed"
    if failed.exists():
        return False
    cmd = [sys.executable, "-m", "skyherd.flight.multirotor.compiled", name]
    try:
        out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
        lines = out.stderr.strip().splitlines()
        why = [ln for ln in lines if "Error" in ln][-1:] or lines[-1:] if out.returncode else None
    except (OSError, subprocess.TimeoutExpired) as e:
        why = [str(e)]
    if why is None and _built(name) is not None:
        return True
    print(f"skyherd: the quadrotor's kernels were not compiled ahead of time ({' '.join(why or [])}); "
          "numba compiles them as before", file=sys.stderr, flush=True)  # fmt: skip
    try:
        failed.parent.mkdir(parents=True, exist_ok=True)
        failed.write_text("\n".join(why or []) + "\n")
    except OSError:
        pass
    return False


def build(name: str) -> Path:
    """Compile the module `name` (numba.pycc) into cache_dir(), replacing older builds: the
    file appears whole (built in a temporary folder, then renamed)."""
    from numba.core import codegen
    from numba.pycc import CC

    from skyherd.flight.multirotor.control import control_step_packed
    from skyherd.flight.quadrotor_kernels import _level_with_yaw

    # the JIT's features, not the CPU model's defaults (a virtual CPU may lack some of those)
    codegen.AOTCPUCodegen._customize_tm_features = codegen.CPUCodegen._get_host_cpu_features
    out = cache_dir()
    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out) as tmp:
        cc = CC(name)
        cc.output_dir = tmp
        cc.target_cpu = "host"  # numba's host CPU name (NUMBA_CPU_NAME when set), as the JIT's
        cc.verbose = False
        funcs = {"control_step_packed": control_step_packed, "level_with_yaw": _level_with_yaw}
        for export, sig in EXPORTS.items():
            cc.export(export, sig)(funcs[export].py_func)
        cc.compile()
        (built,) = Path(tmp).glob(f"{name}.*")
        for old in out.glob(f"{PREFIX}*"):  # other stamps' builds (and failures)
            if old.is_file() and not old.name.startswith(name):
                old.unlink(missing_ok=True)
        target = out / built.name
        os.replace(built, target)
    return target


# ensure_built's child: `python -m skyherd.flight.multirotor.compiled NAME`
if __name__ == "__main__":
    import warnings

    warnings.simplefilter("ignore")  # numba.pycc's pending deprecation: nothing for a user to do
    build(sys.argv[1])
