"""`skyherd fly --connect`: an outside autopilot (here the built-in vehicle in this process,
standing in for PX4 SITL) flown by the companion, free-running on the autopilot's clock, with
the world (UGV team, camera) built around it from its second MAVLink link (`sim --follow`),
following the first autopilot it hears there (system 9 here, not 1).

Free-running involves wall time by nature (the autopilot does not wait): the vehicle runs at
1×, and the companion's setpoints (10 Hz of the vehicle's clock) must keep within its 0.5 s
offboard-loss timeout — the longest the envelope accepts (a longer one is refused before
take-off: tests/e2e/test_fly.py)."""

import json

import pytest

from skyherd.flight.airframes_registry import make_autopilot
from skyherd.flight.mavlink import EndpointConfig
from skyherd.flight.sitl import Sitl
from skyherd.scripts.cli import main

INSTANCE = 8  # the outside vehicle: system 9, API 14580+8 → 14548, ground station → 14550


@pytest.mark.slow
def test_fly_connect_flies_an_outside_autopilot_with_the_world_around_it_walltime(tmp_path):
    ap = make_autopilot("quadrotor", seed=0)
    with Sitl(ap, EndpointConfig(instance=INSTANCE), speedup=1.0).start():
        rc = main(["fly", "--connect", f"udpin:127.0.0.1:{14540 + INSTANCE}", "--duration", "12",
                   "--zenoh-port", "7459", "--instance", "6", "--timeout", "600",
                   "--runs-dir", str(tmp_path)])  # fmt: skip
    (run,) = tmp_path.iterdir()
    comp = json.loads((run / "companion.json").read_text())
    world = json.loads((run / "sim_stats.json").read_text())
    assert rc == 0, (run / "summary.md").read_text()
    assert comp["outcome"] == "completed" and comp["decisions"] >= 20
    assert world["followed"] and world["autopilot"] == "PX4" and world["frames"] > 100
    assert world["system_id"] == INSTANCE + 1  # found by its heartbeat (--world-system 0)
    assert comp["frames"]["ok"] > 50  # the companion saw the world's frames of this vehicle
    assert not ap.armed  # landed and disarmed at the end
