"""numba kernels compiled ahead of time into one extension module, so that a process that only
calls them neither imports numba nor starts its compiler to load them from numba's cache: that
(numba's import, its target registries, SciPy imported for its BLAS check, the cached objects)
cost ~0.5 CPU s in every process that loaded a cached kernel (issue 31). One mechanism for every
package's kernels: a package declares its `AotModule` (flight.multirotor.compiled: the
quadrotor's, safety.compiled: the safety net's) and calls

    kernels()        the compiled module's functions when it is built for these sources on
                     this CPU, else numba's dispatchers of the same functions (the JIT)
    ensure_built()   build the module when it is missing: numba.pycc in a child process, a few
                     CPU s once per change of the kernels' sources (the process's warm-up calls
                     it, where numba compiled the kernels before)

The module's file name carries a stamp of everything its machine code depends on (the kernels'
source files and those of the constants they read, this file, numba's and llvmlite's versions,
the CPU, numba's environment, Python's version), so a stale build is never loaded. numba's
ahead-of-time compiler is given the host CPU's name and features, as its JIT has them: the same
instructions, the same rounding, and the same results to the bit as the JIT's kernels
(docs/topology.md's hashes; tests/flight/test_compiled_kernels.py,
tests/safety/test_safety_compiled.py). A build that fails (no C compiler: tests/runio/test_aot.py)
is said once on stderr and remembered beside it (`<name>.failed`: delete it to try again); the
kernels are then numba's JIT, as before.

An exported function takes exactly the types of its signature: the compiled module converts no
argument (an array of another dtype with the same item size is read as if it were of the
declared one), where the JIT would compile another version. The signatures are the callers'
types; the tests call both with them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.util
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from types import SimpleNamespace


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


def jit_disabled() -> bool:
    """NUMBA_DISABLE_JIT set: the kernels run as Python (numba's dispatchers), never compiled."""
    return os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0")


@dataclasses.dataclass(frozen=True)
class AotModule:
    """One extension module of numba kernels compiled ahead of time.

    prefix:   the module's name before its stamp ("_quad_kernels_")
    what:     the kernels in words, for the message when the build fails
    sources:  the files the kernels' machine code depends on (their own, the constants')
    exports:  name in the module → ("package.module:function", numba signature); the function
              is an njit dispatcher (its py_func is compiled)
    home:     where the module lives without NUMBA_CACHE_DIR (the sources' __pycache__)
    spec:     "package.module:ATTRIBUTE" naming this object, for the build's child process
    """

    prefix: str
    what: str
    sources: tuple[Path, ...]
    exports: dict[str, tuple[str, str]]
    home: Path
    spec: str

    def stamp(self) -> str:
        """The stamp of the kernels' machine code (module docstring)."""
        h = hashlib.sha256()
        for p in (*self.sources, Path(__file__)):
            h.update(p.read_bytes())
        h.update(_version_file("numba") + _version_file("llvmlite") + _cpu())
        numba_env = sorted((k, v) for k, v in os.environ.items() if k.startswith("NUMBA_"))
        h.update(repr([kv for kv in numba_env if kv[0] != "NUMBA_CACHE_DIR"]).encode())
        h.update(sys.version.encode())
        return h.hexdigest()[:16]

    def cache_dir(self) -> Path:
        """Where the compiled module lives: under $NUMBA_CACHE_DIR when it is set, else beside
        the sources' other caches (numba's own choice, __pycache__)."""
        if os.environ.get("NUMBA_CACHE_DIR"):
            return Path(os.environ["NUMBA_CACHE_DIR"]) / "skyherd_aot"
        return self.home

    def is_built(self) -> bool:
        """Whether the module for this stamp is there (kernels() then loads it)."""
        return self._built(self.prefix + self.stamp()) is not None

    def _built(self, name: str) -> Path | None:
        d = self.cache_dir()
        found = sorted(d.glob(f"{name}.*.so")) + sorted(d.glob(f"{name}.*.pyd"))
        return found[0] if found else None

    def jit(self) -> SimpleNamespace:
        """numba's dispatchers of the exported functions (this imports numba)."""
        out = {}
        for export, (where, _sig) in self.exports.items():
            module, func = where.split(":")
            out[export] = getattr(importlib.import_module(module), func)
        return SimpleNamespace(**out)

    def kernels(self) -> SimpleNamespace:
        """The exported functions: the compiled module's when it is built for this stamp, else
        numba's (NUMBA_DISABLE_JIT: always numba's, in Python)."""
        if jit_disabled():
            return self.jit()
        name = self.prefix + self.stamp()
        path = self._built(name)
        if path is None:
            return self.jit()
        spec = importlib.util.spec_from_file_location(name, path)
        try:
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        except (ImportError, OSError):  # replaced meanwhile by another build: numba's kernels
            return self.jit()
        return SimpleNamespace(**{k: getattr(module, k) for k in self.exports})

    def ensure_built(self, timeout_s: float = 600.0) -> bool:
        """Build the compiled module for this stamp when it is missing (a child process; its
        failure is said once on stderr and remembered beside it). True when it is there."""
        if jit_disabled():
            return False
        name = self.prefix + self.stamp()
        if self._built(name) is not None:
            return True
        failed = self.cache_dir() / f"{name}.failed"
        if failed.exists():
            return False
        cmd = [sys.executable, "-m", __name__, self.spec, name]
        try:
            out = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
            lines = out.stderr.strip().splitlines()
            why = (
                [ln for ln in lines if "Error" in ln][-1:] or lines[-1:] if out.returncode else None
            )
        except (OSError, subprocess.TimeoutExpired) as e:
            why = [str(e)]
        if why is None and self._built(name) is not None:
            return True
        print(f"skyherd: {self.what} were not compiled ahead of time ({' '.join(why or [])}); "
              "numba compiles them as before", file=sys.stderr, flush=True)  # fmt: skip
        try:
            failed.parent.mkdir(parents=True, exist_ok=True)
            failed.write_text("\n".join(why or []) + "\n")
        except OSError:
            pass
        return False

    def build(self, name: str) -> Path:
        """Compile the module `name` (numba.pycc) into cache_dir(), replacing this prefix's older
        builds: the file appears whole (built in a temporary folder, then renamed)."""
        from numba.core import codegen
        from numba.pycc import CC

        # the JIT's features, not the CPU model's defaults (a virtual CPU may lack some of those)
        codegen.AOTCPUCodegen._customize_tm_features = codegen.CPUCodegen._get_host_cpu_features
        funcs = self.jit()
        out = self.cache_dir()
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=out) as tmp:
            cc = CC(name)
            cc.output_dir = tmp
            cc.target_cpu = "host"  # numba's host CPU name (NUMBA_CPU_NAME when set), as the JIT's
            cc.verbose = False
            for export, (_where, sig) in self.exports.items():
                cc.export(export, sig)(getattr(funcs, export).py_func)
            cc.compile()
            (built,) = Path(tmp).glob(f"{name}.*")
            for old in out.glob(f"{self.prefix}*"):  # other stamps' builds (and failures)
                if old.is_file() and not old.name.startswith(name):
                    old.unlink(missing_ok=True)
            target = out / built.name
            os.replace(built, target)
        return target


def _spec_object(spec: str) -> AotModule:
    module, attr = spec.split(":")
    return getattr(importlib.import_module(module), attr)


# ensure_built's child: `python -m skyherd.runio.aot package.module:ATTRIBUTE NAME`
if __name__ == "__main__":
    import warnings

    warnings.simplefilter("ignore")  # numba.pycc's pending deprecation: nothing for a user to do
    _spec_object(sys.argv[1]).build(sys.argv[2])
