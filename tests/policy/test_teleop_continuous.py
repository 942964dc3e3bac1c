"""The continuous teleop recorder (issue 29 Deliver 1): MAVLink MANUAL_CONTROL over loopback UDP
recorded as velocity commands within ABS-DL's limits (skyherd-demo/2), replayed with drift 0,
turned into ABS-DL training data as recorded, and accepted by `skyherd train abs-dl --demos`;
a discrete file keeps the skyherd-demo/1 layout and still loads."""

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from skyherd.hil.teleop import manual_control_velocity
from skyherd.policy.absdl.demos import from_recording
from skyherd.policy.absdl.env import velocity_limits
from skyherd.policy.demos import (
    FORMAT,
    FORMAT_CONTINUOUS,
    DemoFileError,
    load_demo,
    record,
    replay,
    scripted_expert,
)
from skyherd.scripts.cli import main
from skyherd.task.params import TaskParams

# (x, y, z, buttons) a scripted stick sends; the last one (button 1) quits
STICK = [
    (500, 0, 500, 0),  # half forward → half the horizontal limit north
    (0, -1000, 500, 0),  # full left → the whole limit west
    (0, 0, 1000, 0),  # full thrust → the climb limit
    (0, 0, 250, 0),  # half down → half the descent limit
    (1000, 1000, 500, 0),  # full diagonal → clipped to the horizontal disc
    (0, 0, 500, 0),  # centred → hold
    (0, 0, 500, 1),
]


def _expected() -> np.ndarray:
    lim = velocity_limits()
    h, d = lim.h_mps, lim.h_mps / np.sqrt(2.0)
    return np.array(
        [
            [h / 2, 0, 0],
            [0, -h, 0],
            [0, 0, -lim.up_mps],
            [0, 0, lim.down_mps / 2],
            [d, d, 0],
            [0, 0, 0],
        ]
    )


@pytest.fixture(scope="module")
def recorded(tmp_path_factory) -> Path:
    """`skyherd teleop --continuous` recording the scripted stick on the composite scenario."""
    from pymavlink.dialects.v20 import common as mavlink2

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = tmp_path_factory.mktemp("teleop") / "composite.npz"
    skyherd = Path(sys.executable).with_name("skyherd")
    cmd = [str(skyherd), "teleop", "--scenario", "composite", "--step-s", "0", "--continuous",
           "--mavlink", f"udpin:127.0.0.1:{port}", "--out", str(out),
           "--runs-dir", str(out.parent / "runs")]  # fmt: skip
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    assert b"teleop ready" in p.stdout.readline()
    mav = mavlink2.MAVLink(None, 255, 190)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for x, y, z, buttons in STICK:
            msg = mavlink2.MAVLink_manual_control_message(1, x, y, z, 0, buttons)
            s.sendto(msg.pack(mav), ("127.0.0.1", port))
            time.sleep(0.05)
    assert p.wait(timeout=30) == 0, p.stdout.read().decode()
    return out


def test_stick_values_come_back_as_the_recorded_velocities(recorded):
    d = load_demo(recorded)
    assert d.meta["format"] == FORMAT_CONTINUOUS
    assert d.meta["demonstrator"] == "mavlink:MANUAL_CONTROL:continuous"
    assert d.vel_ned.shape == (6, 3)
    assert np.allclose(d.vel_ned, _expected(), atol=1e-12)
    assert d.actions.tolist()[:3] == [1, 4, 5]  # nearest rows: north, west, climb
    assert d.actions.tolist()[5] == 0


def test_the_continuous_file_replays_with_drift_zero(recorded):
    assert replay(load_demo(recorded)) == 0.0


def test_from_recording_uses_the_recorded_velocity(recorded):
    d = load_demo(recorded)
    data = from_recording(d, shield=False)
    x, y = data.arrays()
    assert np.allclose(x, d.obs, atol=1e-6)  # replayed states are the recorded ones
    assert np.array_equal(y, d.vel_ned)


def test_train_abs_dl_accepts_a_continuous_file(recorded, tmp_path, capsys):
    args = ["train", "abs-dl", "--demos", str(recorded.parent), "--demo-episodes", "1",
            "--epochs", "1", "--dagger-rounds", "0", "--eval-episodes", "1",
            "--no-shield-comparison", "--runs-dir", str(tmp_path / "runs")]  # fmt: skip
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "recorded demonstrations: composite" in out and "'composite': 6" in out


def test_the_stick_passes_only_the_scenarios_manoeuvres():
    lim = velocity_limits()
    assert np.allclose(manual_control_velocity(500, 500, 1000, "descend", lim), 0.0)
    assert np.allclose(manual_control_velocity(500, 0, 0, "descend", lim), [0, 0, lim.down_mps])
    assert np.allclose(manual_control_velocity(0, 0, 0, "climb", lim), 0.0)
    assert np.allclose(manual_control_velocity(0, 250, 1000, "lateral", lim), [0, lim.h_mps / 4, 0])


def test_a_discrete_file_keeps_format_1_and_still_loads(tmp_path):
    demo = record("climb", scripted_expert("climb"), 1, 7, "scripted", task=TaskParams(episode_s=5))
    path = demo.save(tmp_path / "climb.npz")
    with np.load(path) as z:
        assert sorted(z.files) == sorted(
            ["obs", "actions", "psi", "episode", "t_s", "uav_ned", "ugv_ne", "meta"]
        )
        assert json.loads(str(z["meta"]))["format"] == FORMAT == "skyherd-demo/1"
    back = load_demo(path)
    assert back.vel_ned is None and replay(back) == 0.0
    assert np.array_equal(back.actions, demo.actions)


def test_continuous_needs_the_mavlink_stick(tmp_path, capsys):
    assert main(["teleop", "--continuous", "--runs-dir", str(tmp_path)]) == 2
    assert "--continuous needs --mavlink" in capsys.readouterr().err


def test_a_format_2_file_without_its_velocities_is_refused(recorded, tmp_path):
    with np.load(recorded) as z:
        arrays = {k: z[k] for k in z.files if k != "vel_ned"}
    bad = tmp_path / "composite.npz"
    np.savez(bad, **arrays)
    with pytest.raises(DemoFileError, match="not a readable demonstration"):
        load_demo(bad)
    arrays["vel_ned"] = np.zeros((len(arrays["actions"]), 2))
    np.savez(bad, **arrays)
    with pytest.raises(DemoFileError, match=r"vel_ned is not \(T, 3\)"):
        load_demo(bad)
