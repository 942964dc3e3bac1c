"""Campaign drills flown by the companion's mission code (mission.drill_link, issue 26 Deliver 1):
SingleVehicleMission with the drill's adversarial pilot, the same SafetyNet and judge, over real
loopback MAVLink to the built-in vehicle in lockstep on the simulation clock; the adversary
(fault plan, another client's PARAM_SET, a real cut of the API link) on the vehicle's side.
Seeded, and on the simulation clock only: no wall time, no dependence on machine load."""

import csv
import json

import numpy as np
import pytest

from skyherd.flight.faults import FaultEvent, FaultInjector, FaultPlan
from skyherd.mission import drill_link
from skyherd.mission.drill_link import TICK_S, run_mission_drill
from skyherd.mission.flight import SingleVehicleMission
from skyherd.safety.campaign import kinds_for
from skyherd.scripts.cli import main
from skyherd.world.sim import WorldParams

SEED = 5


class Sink:
    def __init__(self):
        self.records = []

    def write(self, rec):
        self.records.append(rec)


def _caught(r, kind: str) -> None:
    """The attack of `kind` was caught as the drill demands."""
    if kind == "gps_glitch":
        assert any("position jumped" in x for x in r.reasons), r.reasons
    elif kind == "param_sabotage":  # refused with the reason, handed back after the restore
        assert any("autopilot parameters" in x for x in r.reasons), r.reasons
        assert r.restored.startswith(("handed back", "waiting")), r.restored
    elif kind == "link_loss":  # a real cut: what the companion sent meanwhile never arrived
        assert r.cut_dropped > 0
    elif kind == "battery":  # the autopilot's failsafe took over and stood
        assert r.yielded in ("RTL", "LAND"), r.yielded
    elif kind in ("max_speed", "repeat_offender"):  # held at the fence by a fence row
        assert any("field" in x for x in r.reasons), r.reasons


@pytest.mark.parametrize("airframe", ["quadrotor", "fixedwing"])
@pytest.mark.slow
def test_every_kind_through_the_mission_is_judged_and_caught(airframe):
    kinds = kinds_for(airframe)
    for index, kind in enumerate(kinds):
        sink = Sink()
        r = run_mission_drill(kind, airframe, index, SEED, instance=40, events=sink)
        assert r.kind == kind and r.name == f"{kind} {index:04d}"
        assert r.passed, f"{r.name}: {r.why}"
        names = [c.name for c in r.checks]
        assert names[0] == "fence" and "recovered" in names
        assert all(c.ok for c in r.checks), r.why
        assert r.min_clearance_m > 0.0 and r.overridden == 0
        assert r.outcome in ("completed", "yielded"), r.outcome
        assert any(e.get("event") == "handover" for e in sink.records)
        _caught(r, kind)


def test_the_decisions_are_the_missions_records():
    r = run_mission_drill("max_speed", "quadrotor", 0, SEED, instance=40)
    assert r.setpoints == len(r.decisions) > 100  # one per tick of the drill's 0.1 s
    row = r.decisions[0]
    assert row["pilot"] == "drill:max_speed 0000"
    assert {"proposed", "certified", "verdict", "reason", "mode", "autopilot_mode"} <= set(row)
    t = np.array([d["t"] for d in r.decisions])
    assert np.allclose(np.diff(t), TICK_S)  # every lockstep tick decided, none skipped
    assert any(d["verdict"] != "accepted" for d in r.decisions)  # the attack met the net


def test_a_drill_through_the_mission_is_deterministic():
    """Lockstep: the same drill flies the same track, whatever the two threads' timing."""
    a = run_mission_drill("gps_glitch", "quadrotor", 4, SEED, instance=40)
    b = run_mission_drill("gps_glitch", "quadrotor", 4, SEED, instance=40)
    assert len(a.track) == len(b.track) > 100
    assert np.array_equal(np.array(a.track), np.array(b.track))
    assert [d["certified"] for d in a.decisions] == [d["certified"] for d in b.decisions]


def test_the_drill_tick_is_the_flights_tick():
    assert TICK_S == pytest.approx(1.0 / WorldParams().camera_hz)


@pytest.mark.slow
def test_the_campaign_flies_the_mission_code(tmp_path, monkeypatch, capsys):
    """`skyherd drill --campaign` (default --through mission): every drill's decisions come
    from SingleVehicleMission, one mission per drill, and the rows say so."""
    missions = []
    run = SingleVehicleMission.run

    def spy(self, v):
        missions.append(self.pilot.name)
        return run(self, v)

    monkeypatch.setattr(SingleVehicleMission, "run", spy)
    rc = main(["drill", "--campaign", "3", "--seed", str(SEED), "--instance", "40",
               "--runs-dir", str(tmp_path), "--no-plots"])  # fmt: skip
    out = capsys.readouterr().out
    assert rc == 0, out
    assert missions == ["drill:max_speed 0000", "drill:oscillation 0001",
                        "drill:repeat_offender 0002"]  # fmt: skip
    run_dir = next(tmp_path.iterdir())
    rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
    assert [r["through"] for r in rows] == ["mission"] * 3
    assert all(int(r["decisions"]) > 100 and float(r["cpu_s"]) > 0 for r in rows)
    ev = [json.loads(line) for line in (run_dir / "events.jsonl").read_text().splitlines()]
    assert sum(e.get("event") == "handover" for e in ev) == 3
    assert "flown through: the companion's mission code" in out


def test_bad_input_is_a_clear_error():
    with pytest.raises(ValueError, match="kind 'meteor'"):
        run_mission_drill("meteor")
    with pytest.raises(ValueError, match="airframe 'blimp'"):
        run_mission_drill("wind", "blimp")
    rc = main(["drill", "--campaign", "1", "--instance", "999"])
    assert rc == 2


def test_fault_events_move_onto_the_scripts_clock():
    plan = FaultPlan(events=(FaultEvent("gps_glitch", 50.0, 2.0, (5.0, 0.0, 0.0)),))
    inj = FaultInjector(plan, np.random.default_rng(0))
    inj.shift(-40.0, 3.0)
    assert inj.plan.events[0].t0 == pytest.approx(10.0)
    with pytest.raises(ValueError, match="too late"):
        inj.shift(1.0, 12.0)


def test_a_busy_instance_is_skipped():
    """Two drills at once from the same first instance: the second takes the next one."""
    from skyherd.flight.airframes_registry import make_autopilot
    from skyherd.flight.lockstep import LockstepParams

    a = drill_link.open_sitl(make_autopilot("quadrotor"), 40, LockstepParams())
    try:
        b = drill_link.open_sitl(make_autopilot("quadrotor"), 40, LockstepParams())
        assert (a[2], b[2]) == (40, 41)
        b[1].close()
        b[0].close()
    finally:
        a[1].close()
        a[0].close()


def test_the_in_process_loop_is_still_there(tmp_path, capsys):
    """`--through process`: the in-process drill loop (safety.drills.run_drill), no mission."""
    rc = main(["drill", "--campaign", "2", "--through", "process", "--seed", str(SEED),
               "--runs-dir", str(tmp_path), "--no-plots"])  # fmt: skip
    assert rc == 0, capsys.readouterr().out
    rows = list(csv.DictReader(open(next(tmp_path.iterdir()) / "metrics.csv")))
    assert [(r["through"], r["kind"], r["decisions"]) for r in rows] == [
        ("process", "max_speed", ""), ("process", "oscillation", "")]  # fmt: skip
