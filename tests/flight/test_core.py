"""Frames, geodesy, clock and run-folder basics."""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from skyherd.flight.clock import Pacer, SimClock
from skyherd.flight.frames import (
    enu_to_ned,
    euler_to_quat,
    ned_to_enu,
    quat_ned_to_enu,
    quat_to_dcm,
    quat_to_euler,
    yaw_enu_to_ned,
    yaw_ned_to_enu,
)
from skyherd.flight.geo import DEFAULT_HOME, Home, geodetic_to_ned, ned_to_geodetic
from skyherd.runio.runfolder import RunFolder, markdown_table


def test_ned_enu_both_ways():
    v = np.array([1.0, 2.0, 3.0])  # 1 m north, 2 m east, 3 m down
    assert np.allclose(ned_to_enu(v), [2.0, 1.0, -3.0])
    assert np.allclose(enu_to_ned(ned_to_enu(v)), v)
    assert math.isclose(yaw_ned_to_enu(0.0), math.pi / 2)  # north is +y in ENU
    assert math.isclose(yaw_enu_to_ned(yaw_ned_to_enu(0.7)), 0.7)


def test_euler_quat_roundtrip_and_dcm():
    for r, p, y in [(0.1, -0.2, 0.3), (0.0, 0.0, -3.0), (-1.0, 1.2, 2.0)]:
        q = euler_to_quat(r, p, y)
        assert np.isclose(np.linalg.norm(q), 1.0)
        assert np.allclose(quat_to_euler(q), (r, p, y))
    # yaw 90 deg: body forward points east
    r = quat_to_dcm(euler_to_quat(0, 0, math.pi / 2))
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-12)


def test_quat_ned_to_enu_maps_axes():
    # level, heading north: body forward (x FLU) = north = ENU +y, body up = ENU +z
    q = quat_ned_to_enu(euler_to_quat(0, 0, 0))
    x, y, z, w = q
    rot = quat_to_dcm(np.array([w, x, y, z]))
    assert np.allclose(rot @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    assert np.allclose(rot @ [0, 0, 1], [0, 0, 1], atol=1e-12)


def test_geodetic_roundtrip_and_scale():
    ned = np.array([100.0, -250.0, -20.0])
    lat, lon, alt = ned_to_geodetic(DEFAULT_HOME, ned)
    assert math.isclose(alt, 604.0)
    assert np.allclose(geodetic_to_ned(DEFAULT_HOME, lat, lon, alt), ned, atol=1e-6)
    # one arc-second of latitude is about 30.8 m
    n = geodetic_to_ned(DEFAULT_HOME, DEFAULT_HOME.lat_deg + 1 / 3600, DEFAULT_HOME.lon_deg, 584.0)
    assert 30.7 < n[0] < 30.9


def test_home_parse():
    assert Home.parse("-35.1,149.2,500") == Home(-35.1, 149.2, 500.0)
    with pytest.raises(ValueError):
        Home.parse("1,2")
    with pytest.raises(ValueError):
        Home.parse("100,2,3")


def test_clock_exact_and_monotonic():
    c = SimClock()
    for _ in range(1000):
        c.advance(1000)
    assert c.time_us == 1_000_000 and c.t == 1.0 and c.time_boot_ms == 1000
    with pytest.raises(ValueError):
        c.advance(0)
    with pytest.raises(ValueError):
        Pacer(speedup=0.5)
    assert Pacer(speedup=10).sim_to_wall(1.0) == pytest.approx(0.1)


def test_run_folder_files(tmp_path):
    run = RunFolder("fly", root=tmp_path)
    run.write_config({"seed": 0, "arr": np.arange(3)})
    cfg = json.loads((run.path / "config.json").read_text())
    assert cfg["seed"] == 0 and cfg["arr"] == [0, 1, 2] and "numpy" in cfg["versions"]
    ev = run.events()
    ev.write({"t": 1.0, "reason": "ceiling 120 m"})
    ev.close()
    m = run.metrics(["t", "x"])
    m.write({"t": 0.0, "x": 1})
    m.close()
    assert (run.path / "metrics.csv").read_text().splitlines() == ["t,x", "0.0,1"]
    assert RunFolder("fly", root=tmp_path).path != run.path
    assert "| a " in markdown_table(["a", "b"], [[1, 2.5]])


def test_cli_help_lists_commands():
    out = subprocess.run(
        [sys.executable, "-m", "skyherd.scripts.cli", "--help"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    for name in ("sitl", "fly", "drill", "train", "teleop", "watch"):
        assert name in out


def test_exit_now_runs_atexit_flushes_output_and_waits_for_a_working_thread(tmp_path):
    """`exit_now` (how `skyherd` and its children end) skips only the interpreter's teardown:
    the exit code, buffered output, atexit handlers and a non-daemon thread's work survive."""
    done, late = tmp_path / "atexit", tmp_path / "thread"
    code = f"""
import atexit, sys, threading, time
from pathlib import Path
from skyherd.runio.process import exit_now
atexit.register(lambda: Path({str(done)!r}).write_text("ran"))
sys.stdout.write("buffered, no newline")
def work():
    time.sleep(0.3)
    Path({str(late)!r}).write_text("finished")
threading.Thread(target=work).start()
exit_now(3)
"""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # output is buffered
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=env)  # fmt: skip
    assert r.returncode == 3, r.stderr
    assert r.stdout == "buffered, no newline"
    assert done.read_text() == "ran" and late.read_text() == "finished"
    code = code.replace("threading.Thread(target=work).start()", "")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env=env)  # fmt: skip
    assert (r.returncode, r.stdout, done.read_text()) == (3, "buffered, no newline", "ran")


@pytest.mark.parametrize(
    "argv",
    [
        ["sitl"],
        ["fly"],
        ["drill"],
        ["train"],
        ["train", "sql"],
        ["train", "irl"],
        ["train", "ab"],
        ["teleop"],
        ["watch"],
    ],  # fmt: skip
)
def test_every_command_has_help(argv, capsys):
    from skyherd.scripts.cli import main

    with pytest.raises(SystemExit) as e:
        main([*argv, "--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: skyherd " + " ".join(argv)) and "--help" in out


def test_unknown_command_is_bad_usage(capsys):
    from skyherd.scripts.cli import main

    with pytest.raises(SystemExit) as e:
        main(["bogus"])
    assert e.value.code == 2
    assert main([]) == 2
