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
