"""`skyherd sim --autopilot px4`: a PX4 autopilot flies on skyherd's physics (hil/px4_sim.py) and
the world renders the UGV team around it on that simulation clock. The PX4 side here is the
scripted peer that follows PX4's simulator protocol byte for byte (hil/bridge_peers.py; a real
PX4 flies it in tests/e2e/test_bridge_autopilots.py when SKYHERD_PX4_BIN names one)."""

import csv
import json
import subprocess
import sys

from skyherd.hil.bridge_peers import Px4SimPeer

INSTANCE = 76  # TCP 4560+76


def test_sim_with_px4_on_our_physics_renders_the_world_on_its_clock(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    sim = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "sim", "--autopilot", "px4", "--instance", str(INSTANCE),
         "--speedup", "0", "--duration", "4", "--zenoh-port", "7483", "--run-dir", str(run)],
        stdout=open(run / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    peer = Px4SimPeer(port=4560 + INSTANCE)
    try:
        peer.connect(timeout_s=60.0)
        peer.run(4 * 250, timeout_s=60.0)  # 4 s of 250 Hz frames, each answered
    finally:
        peer.close()
        assert sim.wait(60) == 0, (run / "sim.log").read_text()[-2000:]
    stats = json.loads((run / "sim_stats.json").read_text())
    assert stats["bridged"] and stats["sim_s"] >= 4.0
    assert stats["frames"] == 41  # 10 Hz of the bridge's simulation clock, t = 0 … 4 s
    rows = list(csv.DictReader(open(run / "world.csv")))
    assert float(rows[-1]["t"]) >= 3.9 and -float(rows[-1]["down"]) > 1.0  # the script climbs


def test_a_bridged_world_honours_cut_camera_and_a_timed_ugv_start(tmp_path):
    """The options every world shares (world/scene.py): no frame inside a --cut-camera window
    of the bridge's clock, and a team parked until --ugv-start's time."""
    run = tmp_path / "run"
    run.mkdir()
    sim = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "sim", "--autopilot", "px4", "--instance", str(INSTANCE),
         "--speedup", "0", "--duration", "4", "--zenoh-port", "7483", "--run-dir", str(run),
         "--cut-camera", "1:2", "--ugv-start", "2.5"],
        stdout=open(run / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    peer = Px4SimPeer(port=4560 + INSTANCE)
    try:
        peer.connect(timeout_s=60.0)
        peer.run(4 * 250, timeout_s=60.0)
    finally:
        peer.close()
        assert sim.wait(60) == 0, (run / "sim.log").read_text()[-2000:]
    stats = json.loads((run / "sim_stats.json").read_text())
    assert stats["camera_loss_frames"] == 20  # t = 1.0 … 2.9 s at 10 Hz
    assert stats["frames"] == 41 - 20
    rows = list(csv.DictReader(open(run / "world.csv")))
    assert len(rows) == 41  # the truth is kept while the camera is lost
    parked = [r for r in rows if r["team_t"] == ""]
    driving = [r for r in rows if r["team_t"] != ""]
    # the bridge's clock steps 4 ms: a camera instant is within a step of its 0.1 s
    assert len(parked) >= 25 and max(float(r["t"]) for r in parked) < 2.5 + 0.005
    assert min(float(r["t"]) for r in driving) >= 2.5 - 0.005
    first = rows[0]["ugv0_n"], rows[0]["ugv0_e"]
    assert all((r["ugv0_n"], r["ugv0_e"]) == first for r in parked)  # parked: not one move
    assert (rows[-1]["ugv0_n"], rows[-1]["ugv0_e"]) != first


def test_a_bridged_team_waits_for_the_companions_first_decision(tmp_path):
    """--ugv-start offboard beside a bridge (no flight mode on it): the team stays parked until
    the companion's first decision arrives on skyherd/uav0/decision (world/scene.py), and one
    forged without the flight key does not start it."""
    import time

    from skyherd.perception.transport import open_session, subscriber_params
    from skyherd.runio.mac import sign_record

    run = tmp_path / "run"
    run.mkdir()
    key = tmp_path / "k.key"
    key.write_bytes(bytes(range(32)))
    sim = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "sim", "--autopilot", "px4", "--instance", str(INSTANCE),
         "--speedup", "0", "--duration", "4", "--zenoh-port", "7483", "--run-dir", str(run),
         "--signing-key", str(key)],
        stdout=open(run / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    peer = Px4SimPeer(port=4560 + INSTANCE)
    session = open_session(subscriber_params(port=7483))
    try:
        decisions = session.declare_publisher("skyherd/uav0/decision")
        peer.connect(timeout_s=60.0)
        peer.run(250, timeout_s=60.0)  # 1 s
        decisions.put(sign_record({"t": 1.0, "pilot": "policy"}, bytes(32)))  # another key
        time.sleep(1.0)  # [wall s] for it to arrive (it must not count)
        peer.run(250, timeout_s=60.0)  # 2 s
        decisions.put(sign_record({"t": 2.0, "pilot": "policy"}, bytes(range(32))))
        time.sleep(1.0)  # [wall s] for it to arrive before the bridge steps on
        peer.run(2 * 250, timeout_s=60.0)
    finally:
        peer.close()
        session.close()
        assert sim.wait(60) == 0, (run / "sim.log").read_text()[-2000:]
    rows = list(csv.DictReader(open(run / "world.csv")))
    parked = [float(r["t"]) for r in rows if r["team_t"] == ""]
    driving = [float(r["t"]) for r in rows if r["team_t"] != ""]
    assert parked and driving
    # not before the authentic decision (the forged one at 1 s did not start it); at the first
    # camera instant after it arrived: 2.0 or 2.1 s unless Zenoh took over a second of wall
    # time to deliver it, hence the bound at the run's end
    assert 2.0 - 0.005 <= min(driving) < 4.0
    assert max(parked) < min(driving)
