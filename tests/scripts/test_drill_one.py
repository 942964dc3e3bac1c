"""`skyherd drill --campaign N --drill I`: one drill of a campaign again, alone."""

import csv

import pytest


@pytest.mark.slow
def test_drill_flies_one_drill_of_a_campaign_as_the_campaign_flew_it(tmp_path, capsys):
    """`skyherd drill --campaign N --drill I`: drill I of that campaign alone, the same row."""
    from skyherd.scripts.cli import main

    runs = tmp_path / "runs"
    base = ["drill", "--airframe", "quadrotor", "--campaign", "6", "--seed", "3", "--no-plots",
            "--runs-dir", str(runs)]  # fmt: skip
    assert main(base) == 0
    assert main([*base, "--drill", "4"]) == 0
    whole, alone = sorted(runs.iterdir())
    rows = {f: list(csv.DictReader(open(f / "metrics.csv"))) for f in (whole, alone)}
    assert [r["drill"] for r in rows[alone]] == [rows[whole][4]["drill"]]
    same = ("kind", "breach", "min_clearance_m", "passed", "why")
    assert {k: rows[alone][0][k] for k in same} == {k: rows[whole][4][k] for k in same}
    assert "drills 0004 only" in (alone / "summary.md").read_text()
    assert main([*base, "--drill", "6"]) == 2  # outside the campaign
    assert "--drill needs --campaign N and indices within [0, N)" in capsys.readouterr().err
