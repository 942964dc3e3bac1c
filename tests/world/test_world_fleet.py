"""world.fleet: the fleet file written, read back and checked, without argparse."""

import json

import pytest

from skyherd.world.fleet import FleetVehicle, read_fleet, write_fleet


def test_the_fleet_file_round_trips(tmp_path):
    fleet = [FleetVehicle("uav0", 160, 0, (-35.36, 149.16, 584.0)),
             FleetVehicle("uav1", 161, 1, (-35.36, 149.17, 584.0))]  # fmt: skip
    write_fleet(tmp_path / "f.json", fleet)
    assert read_fleet(tmp_path / "f.json") == fleet


@pytest.mark.parametrize(
    "entries, words",
    [
        ([], "non-empty JSON list"),
        ([{"name": "a/b", "instance": 1, "seed": 0, "home": [0, 0, 0]}], "vehicle 0 is not"),
        ([{"name": "a", "instance": 1, "seed": 0, "home": [95, 0, 0]}], "out of range"),
        ([{"name": "a", "instance": 1, "seed": 0, "home": [0, 0, 0]},
          {"name": "b", "instance": 1, "seed": 0, "home": [0, 0, 0]}], "same instance"),
    ],
)  # fmt: skip
def test_a_bad_fleet_file_is_one_line(tmp_path, entries, words):
    f = tmp_path / "f.json"
    f.write_text(json.dumps(entries))
    with pytest.raises(ValueError, match=words):
        read_fleet(f)
