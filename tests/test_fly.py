"""`skyherd fly`: the main job end to end through our own MAVLink client and the built-in SITL."""

import csv

import numpy as np
from pymavlink import mavutil

from scripts.cli import main


def test_fly_square_end_to_end(tmp_path, capsys):
    assert (
        main(
            [
                "fly",
                "--mission",
                "square",
                "--speedup",
                "20",
                "--timeout",
                "120",
                "--runs-dir",
                str(tmp_path),
            ]
        )
        == 0
    )
    (run,) = tmp_path.iterdir()
    assert {"config.json", "telemetry.tlog", "metrics.csv", "track.png", "summary.md"} <= {
        p.name for p in run.iterdir()
    }
    assert "completed" in (run / "summary.md").read_text()
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    pos = np.array([[float(r["north"]), float(r["east"]), float(r["down"])] for r in rows])
    # it reached 20 m, visited every corner of the 40 m square, and came back down
    assert 19.0 < -pos[:, 2].min() < 21.5
    for corner in ([40, 0], [40, 40], [0, 40], [0, 0]):
        assert np.min(np.linalg.norm(pos[:, :2] - corner, axis=1)) < 1.0
    assert -pos[-1, 2] < 0.3
    # the tlog is a real MAVLink log: pymavlink reads our heartbeats and the vehicle's
    log = mavutil.mavlink_connection(str(run / "telemetry.tlog"))
    seen = set()
    while (m := log.recv_match()) is not None:
        seen.add((m.get_type(), m.get_srcSystem()))
    assert {("HEARTBEAT", 1), ("LOCAL_POSITION_NED", 1), ("COMMAND_ACK", 1)} <= seen
    assert ("SET_POSITION_TARGET_LOCAL_NED", 255) in seen


def test_fly_bad_usage_exits_2(tmp_path, capsys):
    assert (
        main(["fly", "--mission", "square", "--altitude", "500", "--runs-dir", str(tmp_path)]) == 2
    )
    assert main(["fly", "--speedup", "0", "--runs-dir", str(tmp_path)]) == 2
    assert main(["fly", "--connect", "bogus", "--runs-dir", str(tmp_path)]) == 2
    assert "expected" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())
