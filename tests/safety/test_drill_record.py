"""Every drill run writes flight.mcap too (record.from_run): each safety-net switch of the drills
is a message on /uav0/safety/event, as in a flight, so a drill opens in Foxglove."""

import json

import pytest

from skyherd.record import read_messages
from skyherd.scripts.cli import main


@pytest.mark.slow
def test_a_drill_run_records_its_events_in_flight_mcap(tmp_path, capsys):
    main(["drill", "--airframe", "quadrotor", "--runs-dir", str(tmp_path)])
    (run,) = tmp_path.iterdir()
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    rec = read_messages(run / "flight.mcap")
    assert rec.complete and len(events) > 10
    assert rec.counts()["/uav0/safety/event"] == len(events)
