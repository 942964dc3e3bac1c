"""Fixed-wing campaign drills through MAVLink (mission.drill_link): `skyherd sitl --airframe
fixedwing`'s vehicle behind its endpoint on loopback UDP; on the companion side the companion's
own code (VehicleLink, mission.steps, mission.companion.run free-running) and the whole safety
net. Paced at 1x wall time (a loaded machine may widen setpoint gaps: the
autopilot's own HOLD then takes over, which the net must not undo; the checks hold either way).
Instances 65-67 (this helper's range)."""

import pytest

from skyherd.mission.drill_link import MAVLINK_KINDS, run_mavlink_drill


@pytest.mark.parametrize(
    ("kind", "instance"), [("battery", 65), ("param_sabotage", 66), ("link_loss", 67)]
)
def test_fixedwing_drill_through_mavlink_walltime(kind, instance):
    index = 1_000_000 + MAVLINK_KINDS.index(kind)
    events = []

    class Sink:
        def write(self, rec):
            events.append(rec)

    r = run_mavlink_drill(kind, instance, seed=41, index=index, events=Sink(),
                          airframe="fixedwing")  # fmt: skip
    assert r.airframe == "fixedwing" and r.name.startswith(kind)
    assert r.passed, r.why
    assert r.overridden == 0
    assert r.min_clearance_m > 0.0  # ground truth inside while the net answers for it
    assert any(e.get("event") == "handover" for e in events)
    if kind == "battery":  # the fixed-wing's own battery failsafe stood
        assert r.yielded in ("RTL", "LAND")
    elif kind == "param_sabotage":  # refused with the reason, then handed back or waiting
        assert any("autopilot parameters" in x for x in r.reasons)
        assert r.restored.startswith(("handed back", "waiting")), r.restored
    else:  # a real cut: what the companion sent meanwhile never reached the vehicle
        assert r.cut_dropped > 0
