"""The judge through the real `skyherd fly` (two programs, lockstep, --speedup 0 unless said):
each false "completed" of issue 26 now ends with exit 1 and the failed check named on the last
line of the report (forced disarm, no frames, an autopilot RTL between two ticks, the truth
beyond the fence).
A normal flight passing every check: tests/e2e/test_fly.py::test_fly_groundair_policy_keeps_the_team_in_view."""

import csv
import json
import socket
import threading
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink.signing import Signing, load_key
from skyherd.safety.config import ENVELOPE_DIR
from skyherd.scripts.cli import main


def _fly(tmp_path, instance: int, *extra: str, duration: str = "15", speedup: str = "0"):
    args = ["fly", "--duration", duration, "--speedup", speedup, "--timeout", "600",
            "--instance", str(instance), "--zenoh-port", str(7456 + instance),
            "--runs-dir", str(tmp_path), *extra]  # fmt: skip
    rc = main(args)
    (run,) = tmp_path.iterdir()
    return rc, run


def _last_line(capsys) -> str:
    """The verdict line: the last line of standard output ("How it ended" goes to stderr)."""
    line = capsys.readouterr().out.splitlines()[-1]
    assert line.startswith("skyherd fly: ") and " run folder " not in line
    return line


def _summary_checks(run: Path) -> dict[str, str]:
    """check name → pass / FAIL, from summary.md's judge table."""
    out = {}
    for line in (run / "summary.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 4 and cells[1] in ("pass", "FAIL"):
            out[cells[0]] = cells[1]
    return out


def _world(run: Path) -> list[dict]:
    with open(run / "world.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_fly_forced_disarm_in_the_air_exits_1_naming_the_check(tmp_path, capsys):
    """A kill switch at t = 15 s (5 s after the hand-over, ~20 m up): the vehicle falls."""
    rc, run = _fly(tmp_path, 29, "--fault", "disarm@15")
    last = _last_line(capsys)
    assert rc == 1 and "first failed check: armed: disarmed at" in last, last
    comp = json.loads((run / "companion.json").read_text())
    assert comp["outcome"] == "aborted" and "disarmed in the air" in comp["reason"]
    assert _summary_checks(run)["armed"] == "FAIL"


@pytest.mark.slow
def test_fly_without_frames_exits_1_naming_the_camera(tmp_path, capsys):
    """The camera never delivers: from the hand-over the net counts it lost (a net event, the
    fallback), and the judge fails the flight on the camera."""
    rc, run = _fly(tmp_path, 30, "--cut-camera", "0:1000")
    last = _last_line(capsys)
    assert rc == 1 and "first failed check: camera: 0 of" in last, last
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    assert any("camera lost" in (e.get("reason") or "") for e in events), events
    assert _summary_checks(run)["camera"] == "FAIL"


@pytest.mark.slow
def test_fly_autopilot_rtl_between_two_ticks_exits_1_wall_time(tmp_path, capsys):
    """RTL at t = 15.02 s and back to OFFBOARD at 15.07 s, between the ticks at 15.0 and 15.1.
    A second component on the onboard link asks the vehicle for 50 Hz heartbeats (as a starved
    companion sees several heartbeats per tick), so RTL shows in heartbeats that arrive with
    the tick at 15.1 s, where the sampled mode is OFFBOARD again. Wall time: the request is
    sent as soon as the simulator's clock runs (--speedup 2: 7 s of wall time before t = 15 s)."""
    instance = 31
    stop = threading.Event()

    def second_component():
        mav = M.MAVLink(None, srcSystem=1 + instance, srcComponent=M.MAV_COMP_ID_UDP_BRIDGE)
        msg = mav.command_long_encode(1 + instance, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                      M.MAVLINK_MSG_ID_HEARTBEAT, 20000, 0, 0, 0, 0, 0)  # fmt: skip
        buf = msg.pack(mav)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # unbound: no port taken
        signing = None
        while not stop.is_set():
            world = list(tmp_path.glob("*/world.csv"))
            rows = world and world[0].read_text().splitlines()
            if rows and len(rows) > 2:
                try:
                    if float(rows[-2].split(",")[0]) > 3.0:  # [-1] may be half written
                        break
                except ValueError:
                    pass
                # the flight is signed (a per-run key): a component of the flight holds the key
                signing = signing or Signing(load_key(world[0].parent / "signing.key"))
                sock.sendto(signing.sign(buf, link_id=5), ("127.0.0.1", 14580 + instance))
            time.sleep(0.05)
        sock.close()

    helper = threading.Thread(target=second_component, daemon=True)
    helper.start()
    try:
        rc, run = _fly(tmp_path, instance, "--fault", "rtl@15.02:0.05", speedup="2")
    finally:
        stop.set()
        helper.join(5)
    last = _last_line(capsys)
    modes = [json.loads(x) for x in (run / "modes.jsonl").read_text().splitlines()]
    rtl = [m for m in modes if m["mode"] == "RTL"]
    assert rtl and rtl[0]["by_companion"] is False and 15.0 <= rtl[0]["t"] < 15.1, modes
    world = {round(float(r["t"]), 1): r["mode"] for r in _world(run)}
    assert world[15.0] == world[15.1] == "OFFBOARD"  # RTL never at a tick's instant
    assert rc == 1 and "modes: RTL at t = 15.00 s" in last, last
    assert _summary_checks(run)["modes"] == "FAIL"


@pytest.mark.slow
def test_fly_truth_beyond_the_fence_exits_1_naming_the_fence(tmp_path, capsys):
    """Issue 26's fence case with the guards on: the north fence edge 35 m out, a 10 s gust
    front of 25 m/s from the south from t = 13.9 s, 5 s after the hand-over (8.9 s since the
    companion asks for its heartbeat at 20 Hz: hil.autopilots.MODE_REPORT_HZ; it was 15 s with the
    hand-over at 10.0 s) (above what the airframe can hold: `--wind`
    that strong is refused before take-off, a wind that rises in flight is not). The net flies
    its fallback; the truth is blown 13.8 m beyond the edge, then the mission lands and ends
    on its own terms. The judge must fail it on the fence. Should the net one day hold it
    inside, the flight is still judged on its truth: no crossing, no fence failure.
    tests/safety/test_safety_judge.py covers the crossing geometry without a flight."""
    base = (ENVELOPE_DIR / "quadrotor_groundair.toml").read_text()
    fence = base.split("[[fence.inclusion]]")[0]
    env = tmp_path.parent / f"{tmp_path.name}-north35.toml"
    env.write_text(fence + '[[fence.inclusion]]\nname = "north 35"\n'
                   "points_ne = [[-200.0, -200.0], [35.0, -200.0], [35.0, 200.0], [-200.0, 200.0]]\n")  # fmt: skip
    rc, run = _fly(tmp_path, 32, "--envelope", str(env), "--fault", "wind@13.9:25,180:10",
                   duration="20")  # fmt: skip
    last = _last_line(capsys)
    comp = json.loads((run / "companion.json").read_text())
    north = max(float(r["north"]) for r in _world(run) if -float(r["down"]) > 0.5)
    if north > 35.0:  # a real crossing by the truth
        assert rc == 1 and "first failed check: fence: closest clearance -" in last, last
        assert f"{35.0 - north:+.2f} m" in last, (north, last)
        assert comp["outcome"] == "completed"  # what `fly` said before the judge: exit 0
    else:
        assert _summary_checks(run)["fence"] == "pass"
