"""`skyherd watch` records the flight it watches (flight.mcap through record.ZenohRecorder)
from a frame source in another process (`skyherd camstream` on port 7468)."""

from __future__ import annotations

import subprocess
import sys

from skyherd.record import read_messages
from skyherd.scripts.cli import main

PORT = 7468


def _watch(tmp_path, *extra) -> int:
    src = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "camstream", "--port", str(PORT), "--frames", "60",
         "--rate", "30", "--wait-s", "60"], stderr=subprocess.DEVNULL,
    )  # fmt: skip
    try:
        return main(["watch", "--connect", f"tcp:127.0.0.1:{PORT}", "--frames", "20",
                     "--timeout", "60", "--no-show", "--runs-dir", str(tmp_path), *extra])  # fmt: skip
    finally:
        src.wait(timeout=120)


def test_watch_writes_flight_mcap_with_frames_poses_and_ugvs(tmp_path):
    assert _watch(tmp_path) == 0
    (run,) = list(tmp_path.iterdir())
    rec = read_messages(run / "flight.mcap")
    c = rec.counts()
    assert rec.complete and c["/uav0/camera/image"] >= 20
    assert c["/uav0/pose"] == c["/tf"] == c["/uav0/camera/image"]
    assert c["/ugvs"] >= 20 - 1  # a scene of the three UGVs per camstream frame
    times = [m.t for m in rec.topic("/uav0/camera/image")]
    assert times == sorted(times) and times[-1] > times[0]  # simulation time, moving
    assert "flight.mcap:" in (run / "summary.md").read_text()


def test_watch_no_mcap_writes_none(tmp_path):
    assert _watch(tmp_path, "--no-mcap") == 0
    (run,) = list(tmp_path.iterdir())
    assert not (run / "flight.mcap").exists() and (run / "metrics.csv").exists()
