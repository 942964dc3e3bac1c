"""`skyherd drill`'s plan without the command line (safety.drill_run): which drills a plan
holds, what config.json records of it, and the events of a flown drill tagged with it."""

import csv

import pytest

from skyherd.runio import CsvWriter
from skyherd.safety.campaign_run import EventSink, load_set
from skyherd.safety.drill_run import COLUMNS, drill_plan, fly_plans


@pytest.fixture(scope="module")
def quad():
    return load_set("quadrotor", None)


def test_only_and_random_choose_the_drills(quad):
    spec, sp = quad
    every = drill_plan("quadrotor", spec, sp)
    assert len(every.scripts) == 10 and every.sp == sp
    plan = drill_plan("quadrotor", spec, sp, "project", 20.0, "ceiling, floor", 2, 7)
    assert [s.name for s in plan.scripts[:2]] == ["ceiling", "floor"]
    assert [s.name.startswith("random") for s in plan.scripts] == [False, False, True, True]
    assert plan.sp.intervention == "project" and plan.p.duration_s == 20.0
    again = drill_plan("quadrotor", spec, sp, "project", 20.0, "ceiling, floor", 2, 7)
    assert [s.start_ned.tolist() for s in again.scripts] == [
        s.start_ned.tolist() for s in plan.scripts
    ]  # the random drills are a function of the seed
    facts = plan.describe()
    assert facts["drills"] == [s.name for s in plan.scripts]
    assert facts["constraint_set_version"] == spec.version
    with pytest.raises(ValueError, match="'nothing' matches no drill; names: .*'ceiling'"):
        drill_plan("quadrotor", spec, sp, only="nothing")
    assert len(drill_plan("quadrotor", spec, sp, only="nothing", n_random=1).scripts) == 1


def test_a_flown_drill_has_its_row_and_its_events_tagged(quad, tmp_path):
    spec, sp = quad
    plan = drill_plan("quadrotor", spec, sp, only="ceiling")
    events, metrics, seen = EventSink(), CsvWriter(tmp_path / "metrics.csv", COLUMNS), []
    ((r, s),) = fly_plans([plan], 0, events, metrics, lambda p, r: seen.append((p, r.name)))
    metrics.close()
    (row,) = csv.DictReader(open(tmp_path / "metrics.csv"))
    assert s is spec and seen == [(plan, "ceiling")] and r.passed
    assert row["drill"] == "ceiling" and row["passed"] == "True" and int(row["switches"]) >= 1
    assert row["constraint_set_version"] == spec.version
    assert events.records
    assert all(e["drill"] == "ceiling" and e["airframe"] == "quadrotor" for e in events.records)
