"""`skyherd drill --resume RUN`: a campaign cut short (killed: metrics.csv ends in part of a row,
events.jsonl holds events of drills that wrote no row) goes on in its folder; the finished
campaign is the uninterrupted one's, row for row and event for event (a drill is a pure function
of its airframe, index and seed), each drill judged once. What cannot be resumed is refused."""

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
N = 6
CAMPAIGN = ["--airframe", "quadrotor", "--campaign", str(N), "--seed", "3", "--through",
            "process", "--no-plots"]  # fmt: skip


def drill(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "skyherd.scripts.cli", "drill", *argv], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)  # fmt: skip


def rows(folder: Path) -> list[dict]:
    with open(folder / "metrics.csv", newline="") as f:
        return [{k: v for k, v in r.items() if k != "cpu_s"} for r in csv.DictReader(f)]


def events(folder: Path) -> list[str]:
    return sorted((folder / "events.jsonl").read_text().splitlines())


@pytest.fixture(scope="module")
def whole(tmp_path_factory) -> Path:
    runs = tmp_path_factory.mktemp("whole")
    p = drill(*CAMPAIGN, "--runs-dir", str(runs))
    assert p.returncode == 0, p.stderr[-2000:]
    (folder,) = runs.iterdir()
    assert len(rows(folder)) == N
    return folder


def cut_short(whole: Path, tmp_path: Path, kept: int) -> Path:
    """The folder as a kill after `kept` rows leaves it: part of the next row written."""
    folder = tmp_path / whole.name
    shutil.copytree(whole, folder)
    (folder / "summary.md").unlink()
    lines = (folder / "metrics.csv").read_text().splitlines(keepends=True)
    (folder / "metrics.csv").write_text("".join(lines[: 1 + kept]) + lines[1 + kept][:17])
    with open(folder / "events.jsonl", "a") as f:
        f.write('{"airframe": "quadrotor", "drill": "torn')  # a torn last event
    return folder


@pytest.mark.slow
def test_a_campaign_cut_short_resumes_to_the_uninterrupted_one(whole, tmp_path):
    folder = cut_short(whole, tmp_path, kept=2)
    p = drill("--resume", str(folder))
    assert p.returncode == 0, p.stderr[-2000:]
    assert f"2 drills judged before, {N - 2} to fly" in p.stdout, p.stdout[-2000:]
    got = rows(folder)
    assert len({r["drill"] for r in got}) == N == len(got)  # each drill once
    assert sorted(got, key=lambda r: r["drill"]) == sorted(rows(whole), key=lambda r: r["drill"])
    assert events(folder) == events(whole)  # none twice, none torn, none lost
    sittings = json.loads((folder / "config.json").read_text())["sittings"]
    assert [s["drills_judged_before"] for s in sittings] == [2]
    summary = (folder / "summary.md").read_text()
    assert f"{N} drills judged" in summary and "2 judged in earlier sittings" in summary


@pytest.mark.slow
def test_resume_refuses_what_is_not_the_same_campaign(whole, tmp_path):
    folder = cut_short(whole, tmp_path, kept=1)
    before = (folder / "metrics.csv").read_bytes(), (folder / "events.jsonl").read_bytes()
    p = drill("--resume", str(folder), "--seed", "4")
    assert p.returncode == 2 and "drop --seed" in p.stderr, p.stderr
    p = drill("--resume", str(tmp_path / "nowhere"))
    assert p.returncode == 2 and "not the run folder of a `skyherd drill --campaign`" in p.stderr
    config = json.loads((folder / "config.json").read_text())
    config["constraint_sets"]["quadrotor"]["version"] = "1999.01-r1"
    (folder / "config.json").write_text(json.dumps(config))
    p = drill("--resume", str(folder))
    assert p.returncode == 2 and "changed since this campaign began" in p.stderr, p.stderr
    after = (folder / "metrics.csv").read_bytes(), (folder / "events.jsonl").read_bytes()
    assert after == before  # nothing flown, nothing cut, nothing written
