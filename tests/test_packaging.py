"""The wheel users install: one top-level module, `skyherd`, with the data the flight needs
(airframes, envelopes, the kept policies, the Zenoh client configuration)."""

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_the_wheel_installs_one_top_level_module(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
         "--wheel-dir", str(tmp_path / "dist"), str(ROOT)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("skyherd-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert {n.split("/")[0] for n in names} == {
        "skyherd",
        wheel.name.split("-py")[0] + ".dist-info",
    }
    for data in ("skyherd/safety/envelopes/quadrotor_groundair.toml",
                 "skyherd/flight/airframes/quadrotor_x.toml",
                 "skyherd/policy/models/groundair_ab.npz",
                 "skyherd/policy/models/groundair_absdl.npz",
                 "skyherd/perception/config/zenoh_router_client.json5"):  # fmt: skip
        assert data in names, data

    target = tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-index",
         "--target", str(target), str(wheel)],
        check=True, capture_output=True, timeout=300,
    )  # fmt: skip
    top = {p.name for p in target.iterdir()} - {"bin"}
    assert top == {"skyherd", wheel.name.split("-py")[0] + ".dist-info"}, top
    # the installed copy, not this source tree: run from elsewhere with the target first
    probe = (f"import sys; sys.path.insert(0, {str(target)!r}); import skyherd, skyherd.scripts.cli; "
             "print(skyherd.__file__)")  # fmt: skip
    out = subprocess.run([sys.executable, "-I", "-c", probe], cwd=tmp_path, check=True,
                         capture_output=True, text=True, timeout=120).stdout  # fmt: skip
    assert out.strip().startswith(str(target)), out
