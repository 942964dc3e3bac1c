"""A campaign drill → its metrics.csv row (safety.campaign_run) and the campaign's exit rule
(safety.campaign_verdict.failed_drills), without the command line."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from skyherd.safety.campaign import KINDS, drill_kind, kinds_for
from skyherd.safety.campaign_run import (
    COLUMNS,
    DrillJob,
    crash_row,
    load_set,
    run_process_drill,
)
from skyherd.safety.campaign_verdict import drill_passed, failed_drills, summarize
from skyherd.safety.config import EnvelopeFileError, default_envelope_path


def test_the_kinds_come_in_turn_and_the_fixedwing_has_no_battery_drill():
    assert [drill_kind("quadrotor", i) for i in range(len(KINDS) + 1)] == [*KINDS, KINDS[0]]
    fw = kinds_for("fixedwing")
    assert "battery" not in fw and len(fw) == len(KINDS) - 1
    assert drill_kind("fixedwing", 6) == fw[6] == "param_sabotage"


def test_the_constraint_set_is_the_airframes_own():
    spec, sp = load_set("quadrotor", None)
    assert spec.airframe == "quadrotor" and sp.intervention
    with pytest.raises(ValueError, match="is for quadrotor, not fixedwing"):
        load_set("fixedwing", default_envelope_path("quadrotor"))
    with pytest.raises(EnvelopeFileError, match="cannot read constraint set"):
        load_set("quadrotor", Path("/no/such/set.toml"))


def test_a_drill_in_the_process_loop_is_one_judged_row():
    row = run_process_drill(DrillJob("quadrotor", 0, 5))
    assert row["drill"] == "max_speed 0000" and row["kind"] == "max_speed"
    assert {k for k in row if not k.startswith("_")} <= set(COLUMNS)
    assert row["passed"] is True and row["failed_check"] == "" and not row["breach"]
    assert row["min_clearance_m"] > 0.0 and row["switches"] >= 1  # caught before the fence
    assert row["constraint_set_version"] == load_set("quadrotor", None)[0].version
    assert len(row["_track"]) > 10 and len(row["_track"][0]) == 3  # NED [m]
    assert row["_events"] and row["_tol"] >= 0.0


def test_a_crash_is_a_failed_row_and_fails_the_campaign():
    crash = crash_row(DrillJob("fixedwing", 7, 1), RuntimeError("boom"))
    assert set(crash) == set(COLUMNS) | {"_events", "_track"}
    assert crash["drill"] == "crashed 0007" and crash["failed_check"] == "crash"
    assert crash["why"] == "RuntimeError: boom" and math.isnan(crash["min_clearance_m"])
    assert not drill_passed(crash)
    ok = {"passed": True}
    assert failed_drills([]) == 0 and failed_drills([ok, ok]) == 0
    assert failed_drills([ok, crash]) == 1


def test_the_exit_rule_reads_rows_back_from_metrics_csv():
    """Read back from metrics.csv the flags are strings: the rule is the same."""
    assert failed_drills([{"passed": "True"}, {"passed": "False"}, {"passed": ""}]) == 2
    row = {"drill": "wind 0005", "airframe": "quadrotor", "kind": "wind", "passed": "False",
           "failed_check": "fence", "min_clearance_m": -0.3, "breach": "True", "overridden": 0,
           "yielded": "", "autopilot_excursion_m": "", "first_reason": "",
           "not_recovered": "False"}  # fmt: skip
    assert summarize([row])[3] == failed_drills([row]) == 1
