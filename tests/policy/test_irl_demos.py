"""Demonstrations: format roundtrip, replay, corrupt files, AB combination rules, teleop via a pty."""

import json
import os
import pty
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from skyherd.policy.ab import RULES, combine
from skyherd.policy.demos import (
    DemoFileError,
    ExpertParams,
    demo_feature_expectations,
    discounted_mean,
    load_demo,
    record,
    replay,
    scripted_expert,
)
from skyherd.policy.groundair.env import PSI_NAMES
from skyherd.task.params import TaskParams

SHORT = TaskParams(episode_s=10.0)


def _demo(scenario="lateral", eps=0.1, n=2):
    ex = scripted_expert(scenario, ExpertParams(epsilon=eps), seed=3)
    return record(scenario, ex, n, 40, "scripted", {"note": "test"}, task=SHORT)


def test_save_load_roundtrip_and_replay(tmp_path):
    d = _demo()
    assert d.actions.shape == (40,) and d.obs.shape == (40, 14) and d.ugv_ne.shape == (40, 3, 2)
    p = d.save(tmp_path / "lateral.npz")
    back = load_demo(p)
    for k in ("obs", "actions", "psi", "episode", "t_s", "uav_ned", "ugv_ne"):
        np.testing.assert_allclose(getattr(back, k), getattr(d, k), rtol=1e-6)
    assert back.meta["format"] == "skyherd-demo/1" and back.meta["note"] == "test"
    assert back.meta["episode_seeds"] == [40, 41]
    assert replay(back, task=SHORT) < 1e-6  # the recorded actions reproduce the recorded run
    # tampering with one action makes replay drift
    back.actions[3] = (back.actions[3] + 1) % 5
    assert replay(back, task=SHORT) > 1e-3


def test_corrupt_and_foreign_files_give_clear_errors(tmp_path):
    p = _demo().save(tmp_path / "d.npz")
    raw = p.read_bytes()
    (tmp_path / "cut.npz").write_bytes(raw[: len(raw) // 3])
    with pytest.raises(DemoFileError, match="not a readable demonstration"):
        load_demo(tmp_path / "cut.npz")
    (tmp_path / "junk.npz").write_bytes(b"\x00" * 100)
    with pytest.raises(DemoFileError):
        load_demo(tmp_path / "junk.npz")
    with pytest.raises(DemoFileError, match="no such"):
        load_demo(tmp_path / "none.npz")
    np.savez(tmp_path / "old.npz", meta=np.array(json.dumps({"format": "v0"})))
    with pytest.raises(DemoFileError):
        load_demo(tmp_path / "old.npz")
    d = _demo()
    d.psi[0, 0] = np.nan
    d.save(tmp_path / "nan.npz")
    with pytest.raises(DemoFileError, match="NaN"):
        load_demo(tmp_path / "nan.npz")
    assert not list(tmp_path.glob(".*tmp*"))


def test_discounted_feature_expectations():
    psi = np.ones((6, 2))
    ep = np.array([0, 0, 0, 1, 1, 1])
    g = 0.5
    # each episode: (1 − γ)(1 + γ + γ²) = 0.875
    np.testing.assert_allclose(discounted_mean(psi, ep, g), [0.875, 0.875])


def test_ab_rules():
    demos = {s: _demo(s, eps=0.0, n=1) for s in ("lateral", "climb", "descend")}
    mus = {s: demo_feature_expectations(d, 0.97) for s, d in demos.items()}
    out = {r: combine(demos, r, 0.97) for r in RULES}
    np.testing.assert_allclose(out["mean"], np.mean(list(mus.values()), axis=0))
    j = PSI_NAMES.index("centred_u")
    assert out["per_feature"][j] == pytest.approx(mus["lateral"][j])
    j = PSI_NAMES.index("spread_30_45")
    assert out["per_feature"][j] == pytest.approx((mus["climb"][j] + mus["descend"][j]) / 2)
    # var_weighted lies inside the sub-tasks' range, feature by feature
    lo = np.min(list(mus.values()), axis=0)
    hi = np.max(list(mus.values()), axis=0)
    assert np.all(out["var_weighted"] >= lo - 1e-9) and np.all(out["var_weighted"] <= hi + 1e-9)
    with pytest.raises(ValueError, match="needs demonstrations"):
        combine({"lateral": demos["lateral"]}, "mean", 0.97)
    with pytest.raises(ValueError, match="recorded on"):
        combine({**demos, "climb": demos["descend"]}, "mean", 0.97)


def test_expert_respects_scenario_manoeuvres():
    for sc, allowed in (("climb", {0, 5}), ("descend", {0, 6}), ("lateral", {0, 1, 2, 3, 4})):
        d = _demo(sc, eps=0.3, n=1)
        assert set(np.unique(d.actions)) <= allowed
        assert len(set(np.unique(d.actions)) - {0}) >= 1  # the manoeuvre is actually needed


def _read_until(fd, marker, timeout_s):
    """Read a pty master until `marker` appears (None: until EOF) or the timeout."""
    import select

    buf, end = b"", time.monotonic() + timeout_s
    while time.monotonic() < end:
        r, _, _ = select.select([fd], [], [], 0.2)
        if not r:
            continue
        try:
            chunk = os.read(fd, 65536)
        except OSError:  # EIO: the child closed the terminal
            break
        if not chunk:
            break
        buf += chunk
        if marker is not None and marker in buf:
            break
    return buf


def test_teleop_records_keys_through_a_pty(tmp_path):
    out = tmp_path / "climb.npz"
    skyherd = Path(sys.executable).with_name("skyherd")
    m, s = pty.openpty()
    cmd = [str(skyherd), "teleop", "--scenario", "climb", "--step-s", "0", "--episode-s", "30"]
    p = subprocess.Popen(cmd + ["--out", str(out)], stdin=s, stdout=s, stderr=s, close_fds=True)
    os.close(s)
    buf = _read_until(m, b"teleop ready", 60)
    os.write(m, b"rrr x dfq")  # climb ×3, hover, 'x' and 'd' and 'f' are not climb → hover, quit
    buf += _read_until(m, None, 60)
    assert p.wait(timeout=30) == 0, buf[-500:]
    d = load_demo(out)
    assert d.actions.tolist() == [5, 5, 5, 0, 0, 0, 0, 0]
    assert d.meta["demonstrator"] == "teleop:keyboard" and d.meta["scenario"] == "climb"
    assert b"recorded 8 steps" in buf


def test_teleop_without_terminal_is_usage_error(tmp_path):
    skyherd = Path(sys.executable).with_name("skyherd")
    r = subprocess.run(
        [str(skyherd), "teleop"], stdin=subprocess.DEVNULL, capture_output=True, text=True
    )
    assert r.returncode == 2 and "needs a terminal" in r.stderr


def test_manual_control_mapping():
    from skyherd.hil.teleop import manual_control_action

    allc = tuple(range(7))
    assert manual_control_action(0, 0, 500, allc) == 0
    assert manual_control_action(800, 100, 500, allc) == 1
    assert manual_control_action(-800, 100, 500, allc) == 2
    assert manual_control_action(100, 900, 500, allc) == 3
    assert manual_control_action(100, -900, 500, allc) == 4
    assert manual_control_action(0, 0, 1000, allc) == 5
    assert manual_control_action(0, 0, 0, allc) == 6
    assert manual_control_action(200, -200, 600, allc) == 0  # inside the dead band
    assert manual_control_action(800, 0, 500, (0, 5)) == 0  # climb-only scenario: north not allowed


def test_teleop_from_mavlink_manual_control(tmp_path):
    import socket

    from pymavlink.dialects.v20 import common as mavlink2

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    out = tmp_path / "d.npz"
    skyherd = Path(sys.executable).with_name("skyherd")
    cmd = [
        str(skyherd),
        "teleop",
        "--scenario",
        "descend",
        "--step-s",
        "0",
        "--mavlink",
        f"udpin:127.0.0.1:{port}",
        "--out",
        str(out),
    ]
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    assert b"teleop ready" in p.stdout.readline()
    mav = mavlink2.MAVLink(None, 255, 190)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        for x, z, buttons in [
            (0, 0, 0),
            (0, 0, 0),
            (0, 500, 0),
            (900, 500, 0),
            (0, 0, 0),
            (0, 500, 1),
        ]:
            msg = mavlink2.MAVLink_manual_control_message(1, x, 0, z, 0, buttons)
            s.sendto(msg.pack(mav), ("127.0.0.1", port))
            time.sleep(0.05)
    assert p.wait(timeout=30) == 0
    d = load_demo(out)
    # descend, descend, hover, north (not allowed in descend → hover), descend, then button 1 quits
    assert d.actions.tolist() == [6, 6, 0, 0, 6]
    assert d.meta["demonstrator"] == "mavlink:MANUAL_CONTROL"
