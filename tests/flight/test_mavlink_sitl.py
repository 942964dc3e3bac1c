"""The SITL runner and `skyherd sitl`: lockstep determinism at any speed-up, the command
line's usage errors, port clashes, the fixed-wing airframe, and the endpoint's building
blocks (mode numbers, stream scheduling, parameter files, framing, setpoint masks)."""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.airframes_registry import AirframeUnavailable, make_autopilot
from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.clock import SimClock
from skyherd.flight.mavlink import EndpointConfig, Personality
from skyherd.flight.mavlink.codec import Codec
from skyherd.flight.mavlink.modes import (
    base_mode_of,
    custom_mode_of,
    mode_name,
    mode_of_custom,
    mode_of_packed,
)
from skyherd.flight.mavlink.offboard import SetpointError, setpoint_from_local
from skyherd.flight.mavlink.params import ParamFile
from skyherd.flight.mavlink.streams import StreamScheduler
from skyherd.flight.sitl import Sitl

ROOT = Path(__file__).resolve().parents[2]
SKYHERD = str(Path(sys.executable).parent / "skyherd")  # the installed console script


def _scripted_flight(speedup: float, instance: int, pause_s: float = 0.0) -> np.ndarray:
    """Arm, take off to 6 m, offboard velocity east: the same inputs at the same sim steps."""
    ap = make_autopilot("quadrotor", clock=SimClock())

    def script(sitl: Sitl) -> None:
        k = sitl.steps
        if k == 10:
            ap.arm()
        elif k == 20:
            ap.takeoff(6.0)
        elif k >= 1000:
            ap.set_offboard_setpoint(Setpoint(vel_ned=np.array([0.0, 2.0, 0.0]), yaw=0.0))
            if k == 1010:
                ap.set_mode(FlightMode.OFFBOARD)

    with Sitl(ap, EndpointConfig(instance=instance), speedup=speedup) as sitl:
        sitl.run(duration_s=3.0, on_step=script)
        if pause_s:
            import time

            time.sleep(pause_s)
        sitl.run(duration_s=3.0, on_step=script)
        s = ap.state
        return np.concatenate([[s.t], s.pos_ned, s.vel_ned, s.quat, s.omega_frd])


def test_lockstep_same_trajectory_at_any_speedup_and_after_a_pause():
    fast = _scripted_flight(0.0, instance=17)
    paced = _scripted_flight(20.0, instance=17, pause_s=0.3)
    assert fast[0] == pytest.approx(6.0)
    assert fast[3] < -5.0 and fast[5] > 1.0  # climbed, flying east
    assert np.array_equal(fast, paced)  # bit for bit


def _cli(*args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run([SKYHERD, "sitl", *args], cwd=ROOT,
                          capture_output=True, text=True, timeout=timeout)  # fmt: skip


def test_cli_usage_errors_exit_2(tmp_path, capsys):
    from skyherd.scripts.cli import main

    for args, words in (
        (["--speedup", "0.5"], "--speedup"),
        (["--home", "100,0,0"], "--home"),
        (["--home", "abc"], "--home"),
        (["--instance", "999"], "--instance"),
        (["--duration", "-1"], "--duration"),
    ):
        assert main(["sitl", *args, "--runs-dir", str(tmp_path)]) == 2, args
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1
    # A bad signing key file and a runs dir that cannot be written: one line, exit 2.
    short = tmp_path / "short.key"
    short.write_bytes(b"k" * 31)
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    unwritable = ro if not os.access(ro, os.W_OK) else Path("/sys")  # root ignores chmod
    for args, words in (
        (["--signing-key", str(short), "--runs-dir", str(tmp_path)], "32"),
        (["--runs-dir", str(unwritable / "runs")], "--runs-dir"),
    ):
        assert main(["sitl", "--instance", "64", "--duration", "1", *args]) == 2, args
        err = capsys.readouterr().err
        assert words in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_cli_runs_fixedwing_and_reports_a_port_clash(tmp_path):
    first = subprocess.Popen([SKYHERD, "sitl", "--airframe", "fixedwing",
                              "--instance", "16", "--speedup", "1", "--duration", "30", "--no-tlog",
                              "--runs", str(tmp_path), "--state-dir", str(tmp_path / "s")],
                             cwd=ROOT, stdout=subprocess.PIPE, text=True)  # fmt: skip
    try:
        assert "fixedwing, system id 17" in first.stdout.readline()
        clash = _cli(
            "--instance", "16", "--runs", str(tmp_path), "--state-dir", str(tmp_path / "s")
        )
        assert clash.returncode == 2 and "cannot bind UDP 127.0.0.1:14596" in clash.stderr
    finally:
        first.terminate()
        assert first.wait(timeout=10) == 0  # SIGTERM ends it cleanly
    r = _cli("--airframe", "fixedwing", "--instance", "16", "--speedup", "0", "--duration", "2",
             "--runs", str(tmp_path / "b"), "--state-dir", str(tmp_path / "s"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    folder = next((tmp_path / "b").glob("*-sitl"))
    cfg = json.loads((folder / "config.json").read_text())
    assert cfg["airframe"] == "fixedwing" and cfg["endpoint"]["instance"] == 16
    # The tlog is readable by pymavlink and starts with our heartbeat: a fixed-wing, system 17.
    from pymavlink import mavutil

    log = mavutil.mavlink_connection(str(folder / "telemetry.tlog"))
    hb = log.recv_match(type="HEARTBEAT")
    assert hb.type == M.MAV_TYPE_FIXED_WING and hb.get_srcSystem() == 17


def test_registry():
    assert make_autopilot("quadrotor").airframe == "quadrotor"
    with pytest.raises(AirframeUnavailable, match="unknown airframe"):
        make_autopilot("blimp")


def test_mode_numbers_px4_and_ardupilot():
    px4, apm = Personality.PX4, Personality.ARDUPILOT
    assert custom_mode_of(px4, FlightMode.OFFBOARD) == 6 << 16
    assert custom_mode_of(px4, FlightMode.MISSION) == (4 << 16) | (4 << 24)
    assert custom_mode_of(px4, FlightMode.LAND) == (4 << 16) | (6 << 24)
    for mode in FlightMode:
        assert mode_of_packed(px4, custom_mode_of(px4, mode)) == mode
    assert mode_of_custom(px4, 4, 1) == FlightMode.HOLD  # AUTO.READY
    assert mode_of_custom(px4, 5, 0) is None  # ACRO: not available
    assert mode_of_custom(px4, math.nan, 0) is None and mode_of_custom(px4, 2.5, 0) is None
    assert [
        custom_mode_of(apm, m)
        for m in (FlightMode.MISSION, FlightMode.HOLD, FlightMode.RTL, FlightMode.LAND)
    ] == [3, 17, 6, 9]  # HOLD shows as BRAKE: LOITER reads a pilot's throttle
    assert mode_of_custom(apm, 17, 0) == FlightMode.HOLD  # BRAKE
    assert (
        mode_name(px4, FlightMode.HOLD) == "AUTO.LOITER"
        and mode_name(apm, FlightMode.OFFBOARD) == "GUIDED"
    )
    # A fixed-wing with the ardupilot personality shows ArduPlane numbers.
    assert [custom_mode_of(apm, m, "fixedwing") for m in (FlightMode.HOLD, FlightMode.MISSION, FlightMode.OFFBOARD,
                                                           FlightMode.TAKEOFF, FlightMode.RTL)] == [12, 10, 15, 13, 11]  # fmt: skip
    assert (
        mode_of_custom(apm, 1, 0, "fixedwing") == FlightMode.HOLD
        and mode_of_custom(apm, 9, 0, "fixedwing") is None
    )
    assert mode_name(apm, FlightMode.HOLD, "fixedwing") == "LOITER"
    bm = base_mode_of(FlightMode.HOLD, armed=True)
    assert bm & M.MAV_MODE_FLAG_SAFETY_ARMED and bm & M.MAV_MODE_FLAG_AUTO_ENABLED
    assert base_mode_of(FlightMode.POSCTL, armed=False) & M.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED


def test_stream_scheduler_counts_on_sim_time():
    s = StreamScheduler({1: 10.0, 2: 1.0, 3: 0.0})
    sent = {1: 0, 2: 0, 3: 0}
    for k in range(2500):  # 10 s at 250 Hz
        for m in s.due(k * 0.004):
            sent[m] += 1
    assert sent == {1: 100, 2: 10, 3: 0}
    assert s.set_interval(3, 200_000) and s.interval_us(3) == 200_000
    assert (
        not s.set_interval(99, 1000)
        and not s.set_interval(1, -7)
        and not s.set_interval(1, math.nan)
    )
    assert s.set_interval(1, -1) and s.interval_us(1) == -1
    assert s.set_interval(1, 0) and s.rates[1] == 10.0


def test_param_file_corrupt_or_odd_gives_defaults_with_a_warning(tmp_path, caplog):
    path = tmp_path / "p" / "params.json"
    pf = ParamFile(path)
    assert pf.load() == {}
    pf.save({"A": 1.5, "B": -2.0})
    assert pf.load() == {"A": 1.5, "B": -2.0}
    assert [p.name for p in path.parent.iterdir()] == ["params.json"]  # no temp file left
    for text in (
        "{not json",
        "[1, 2]",
        '{"version": 2, "params": {}}',
        '{"version": 1, "params": 3}',
        "\xff\xfe",
    ):
        path.write_text(text, encoding="latin-1")
        with caplog.at_level(logging.WARNING):
            caplog.clear()
            assert pf.load() == {}
            assert "using defaults" in caplog.text
    path.write_text('{"version": 1, "params": {"A": 1.0, "B": "x", "C": NaN, "D": true}}')
    assert pf.load() == {"A": 1.0}


def test_codec_frames_v1_v2_truncated_and_bad_crc():
    tx = M.MAVLink(None, 255, 190)
    v2 = bytes(tx.heartbeat_encode(6, 8, 0, 0, 0).pack(tx))
    v1 = bytes(tx.heartbeat_encode(6, 8, 0, 0, 0).pack(tx, force_mavlink1=True))
    c = Codec(1, 1)
    assert [m.get_type() for m in c.parse(v2 + v1)] == ["HEARTBEAT", "HEARTBEAT"]
    assert c.parse(v2[:-3]) == [] and c.parse(v2[:-1] + bytes([v2[-1] ^ 1])) == []
    assert c.parse(v2) != []  # a truncated datagram does not poison the next one
    assert c.stats.rx_bad == 2 and c.stats.rx_frames == 3


def test_offboard_type_mask():
    tx = M.MAVLink(None, 255, 190)

    def msg(mask, frame=M.MAV_FRAME_LOCAL_NED, x=1.0, vx=2.0, yaw=0.5):
        return tx.set_position_target_local_ned_encode(
            0, 1, 1, frame, mask, x, 2, -3, vx, 0, 0, 0, 0, 0, yaw, 0.1
        )

    sp = setpoint_from_local(msg(0b1001_1111_1000))  # position + yaw
    assert (
        sp.pos_ned.tolist() == [1, 2, -3]
        and sp.vel_ned is None
        and sp.yaw == 0.5
        and sp.yaw_rate is None
    )
    sp = setpoint_from_local(msg(0b0101_1100_0111))  # velocity + yaw rate
    assert sp.pos_ned is None and sp.vel_ned.tolist() == [2, 0, 0] and sp.yaw is None
    assert sp.yaw_rate == pytest.approx(0.1)
    for bad in (msg(0b1001_1111_1010), msg(0b0000_1111_1111_1111), msg(0, frame=M.MAV_FRAME_BODY_FRD),
                msg(0b1001_1111_1000, x=math.nan), msg(0b0101_1100_0111, vx=1e3)):  # fmt: skip
        with pytest.raises(SetpointError):
            setpoint_from_local(bad)


def test_parameters_saved_in_the_state_dir_are_announced_and_recorded(tmp_path, capsys):
    """A value a previous run saved (over MAVLink, in --state-dir) is loaded again: said at
    start-up with the file and how to start from the defaults, and in config.json."""
    from skyherd.flight.mavlink.params import ParamFile
    from skyherd.scripts.cli import main

    state = tmp_path / "state"
    ParamFile(state / "quadrotor-65" / "params.json").save({"MPC_XY_VEL_MAX": 7.0})
    assert main(["sitl", "--instance", "65", "--speedup", "0", "--duration", "0.5", "--no-tlog",
                 "--state-dir", str(state), "--runs-dir", str(tmp_path / "runs")]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert "1 parameter saved in" in out and "MPC_XY_VEL_MAX=7" in out and "--state-dir" in out
    (run,) = (tmp_path / "runs").iterdir()
    saved = json.loads((run / "config.json").read_text())["params_saved"]
    assert saved["values"] == {"MPC_XY_VEL_MAX": 7.0}
    assert saved["file"].endswith("quadrotor-65/params.json")
