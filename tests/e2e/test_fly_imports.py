"""What `make run`'s three processes import (issue 31: start-up off the critical path), watched
in a real `skyherd fly` by an import hook in each process (a sitecustomize on PYTHONPATH that
logs the first import of each watched package, with the Python stack that asked for it):

- the simulator imports no numba (its kernels run compiled ahead of time: flight.multirotor.
  compiled), no SciPy, no pydantic (the default tables are plain: runio.schema), no matplotlib;
- the companion imports no pydantic, no matplotlib, no OSQP and no SciPy (its net's projection
  and recovery target are exact: safety.nearest);
- `fly`'s recorder imports neither the MCAP reader (record.read) nor, without --foxglove, the
  live view (record.live);
- `fly` imports matplotlib only to draw its plots after the verdict (report.ending.make_plots),
  no pydantic; its checks of the children's arguments build the simulator's parameter records
  (world.params, flight.mavlink.config), read keys (flight.mavlink.keys) and check addresses
  (hil.addresses) without the simulator's stack: no world.sim or world.scene, no MAVLink
  endpoint or link, no pymavlink, and OpenCV only for the recorder's frames;
- none of them imports torch or pandas.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from skyherd.flight.multirotor import compiled

WATCHED = ("numba", "scipy", "osqp", "pydantic", "matplotlib", "torch", "pandas", "cv2")
WATCHED += ("pymavlink", "skyherd.world.sim", "skyherd.world.scene")
WATCHED += ("skyherd.flight.mavlink.endpoint", "skyherd.hil.link")  # modules: full names
WATCHED += ("skyherd.record.read", "skyherd.record.live")

HOOK = f"""
import json, os, sys, traceback

WATCHED = {WATCHED!r}


class _Watch:
    def find_spec(self, name, path=None, target=None):
        if name in WATCHED and name not in sys.modules:
            argv = open("/proc/self/cmdline", "rb").read().split(b"\\0")
            role = next((a.decode() for a in argv if a in (b"fly", b"sim", b"companion")), "?")
            stack = [f.name for f in traceback.extract_stack()]
            if "_find_and_load" not in stack:  # a look-up (importlib.util.find_spec), no import
                return None
            with open(os.environ["SKYHERD_IMPORT_LOG"], "a") as f:
                f.write(json.dumps({{"role": role, "module": name, "stack": stack}}) + "\\n")
        return None


sys.meta_path.insert(0, _Watch())
"""


@pytest.fixture(scope="module")
def imports(tmp_path_factory) -> dict[str, dict[str, list[str]]]:
    """role → {package → the stack of its first import} over one short ground-air flight."""
    assert compiled.ensure_built()  # as the simulator's warm-up would, before the flight
    tmp = tmp_path_factory.mktemp("imports")
    (tmp / "hook").mkdir()
    (tmp / "hook" / "sitecustomize.py").write_text(HOOK)
    log = tmp / "imports.jsonl"
    env = dict(os.environ, SKYHERD_IMPORT_LOG=str(log))
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(tmp / "hook"), env.get("PYTHONPATH")]))
    cmd = [sys.executable, "-m", "skyherd.scripts.cli", "fly", "--duration", "5", "--speedup",
           "0", "--instance", "82", "--runs-dir", str(tmp / "runs")]  # fmt: skip
    out = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-2000:]
    seen: dict[str, dict[str, list[str]]] = {"fly": {}, "sim": {}, "companion": {}}
    for line in log.read_text().splitlines() if log.exists() else []:
        rec = json.loads(line)
        seen.setdefault(rec["role"], {}).setdefault(rec["module"], rec["stack"])
    return seen


@pytest.mark.slow
def test_the_simulator_imports_no_numba_scipy_pydantic_or_plotting(imports):
    assert not set(imports["sim"]) & {"numba", "scipy", "pydantic", "matplotlib"}, {
        m: s[-6:] for m, s in imports["sim"].items()
    }


@pytest.mark.slow
def test_the_companion_imports_no_pydantic_plotting_osqp_or_scipy(imports):
    assert not set(imports["companion"]) & {"pydantic", "matplotlib", "osqp", "scipy"}, {
        m: s[-6:] for m, s in imports["companion"].items()
    }


@pytest.mark.slow
def test_fly_imports_matplotlib_only_for_its_plots_after_the_verdict(imports):
    assert "matplotlib" in imports["fly"]  # the plots were made
    assert "make_plots" in imports["fly"]["matplotlib"]  # ... after the verdict, not before
    assert "pydantic" not in imports["fly"]


@pytest.mark.slow
def test_fly_checks_its_children_without_the_simulators_stack(imports):
    """fly's checks (world.setup.SimSetup.checked, the companion's check) and its recorder
    import neither the simulator's world nor the MAVLink stack; OpenCV only for the recorder's
    frames (record.flightlog's JPEGs), never for a check."""
    sim_stack = {"pymavlink", "skyherd.world.sim", "skyherd.world.scene"}
    sim_stack |= {"skyherd.flight.mavlink.endpoint", "skyherd.hil.link"}
    assert not set(imports["fly"]) & sim_stack, {
        m: s[-8:] for m, s in imports["fly"].items() if m in sim_stack
    }
    assert "_recorder" in imports["fly"]["cv2"], imports["fly"]["cv2"][-8:]
    assert "_validate" not in imports["fly"]["cv2"], imports["fly"]["cv2"][-8:]
    assert {"cv2", "pymavlink", "skyherd.world.sim"} <= set(imports["sim"])  # the hook saw them


@pytest.mark.slow
def test_fly_records_without_the_reader_or_the_live_view(imports):
    """fly writes flight.mcap and reads nothing back (record.read); without --foxglove it
    starts no live view (record.live): skyherd.record imports each name when it is asked for."""
    assert not set(imports["fly"]) & {"skyherd.record.read", "skyherd.record.live"}, {
        m: s[-8:] for m, s in imports["fly"].items() if m.startswith("skyherd.record")
    }


@pytest.mark.slow
def test_no_process_of_the_flight_imports_torch_or_pandas(imports):
    for role, mods in imports.items():
        assert not set(mods) & {"torch", "pandas"}, (role, sorted(mods))


def test_the_hook_sees_an_import(tmp_path):
    """The watcher itself works: a process that imports a watched package is logged."""
    (tmp_path / "sitecustomize.py").write_text(HOOK)
    log = tmp_path / "log.jsonl"
    env = dict(os.environ, SKYHERD_IMPORT_LOG=str(log), PYTHONPATH=str(tmp_path))
    subprocess.run([sys.executable, "-c", "import pydantic"], env=env, check=True, timeout=60)
    assert [json.loads(ln)["module"] for ln in log.read_text().splitlines()] == ["pydantic"]
