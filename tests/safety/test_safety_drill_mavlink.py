"""Campaign drills through MAVLink (issue 11.5): the built-in vehicle's endpoint on loopback
UDP (instance 86), the companion's own code on the other side (mission.drill_link: VehicleLink,
mission.steps, mission.companion.run free-running), the whole safety net in between. Paced
at 1x wall time: a setpoint gap under a loaded machine ends in the autopilot's own HOLD, which
the net must then not undo (the checks hold either way)."""

import csv
import json

from skyherd.scripts.cli import main


def test_max_speed_and_battery_drills_through_mavlink_walltime(tmp_path, capsys):
    rc = main(["drill", "--mavlink", "2", "--instance", "86", "--seed", "3",
               "--runs-dir", str(tmp_path)])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "| max_speed 1000000" in out and "| battery 1000001" in out
    run = next(tmp_path.iterdir())
    ev = [json.loads(line) for line in (run / "events.jsonl").read_text().splitlines()]
    handovers = [e for e in ev if e.get("event") == "handover"]
    assert len(handovers) == 2
    battery = [e for e in ev if e["drill"].startswith("mavlink battery")]
    assert any(e.get("event") == "yield" and e["autopilot_mode"] in ("RTL", "LAND", "HOLD")
               for e in battery)  # fmt: skip
    assert "overridden" in out and list(csv.DictReader(open(run / "metrics.csv"))) == []
