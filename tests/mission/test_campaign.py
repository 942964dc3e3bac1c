"""The campaign's runner (mission.campaign) without the command line: its jobs, a crashed drill,
the rows in order on one worker."""

from __future__ import annotations

from pathlib import Path

from skyherd.mission.campaign import campaign_jobs, run_all, run_one
from skyherd.safety.campaign_run import COLUMNS, DrillJob


def test_the_jobs_go_drill_by_drill_the_airframes_in_turn():
    jobs = campaign_jobs(["quadrotor", "fixedwing"], 2, 7, None, "mission", 150)
    assert [(j.airframe, j.index) for j in jobs] == [
        ("quadrotor", 0), ("fixedwing", 0), ("quadrotor", 1), ("fixedwing", 1),
    ]  # fmt: skip
    assert {(j.seed, j.through, j.instance, j.envelope) for j in jobs} == {
        (7, "mission", 150, None)
    }


def test_a_drill_that_raises_is_a_crashed_row_not_a_lost_campaign():
    row = run_one(DrillJob("quadrotor", 3, 0, Path("/no/such/set.toml")))
    assert row["kind"] == "crash" and row["passed"] is False and row["failed_check"] == "crash"
    assert row["why"].startswith("EnvelopeFileError: cannot read constraint set")
    assert row["through"] == "" and set(row) == set(COLUMNS) | {"_events", "_track"}


def test_one_worker_gives_the_rows_in_job_order_with_the_way_they_flew():
    jobs = campaign_jobs(["quadrotor"], 2, 5, None, "process", 150)
    rows = list(run_all(jobs, workers=1))
    assert [r["drill"] for r in rows] == ["max_speed 0000", "oscillation 0001"]
    assert all(r["through"] == "process" and r["cpu_s"] >= 0.0 for r in rows)
