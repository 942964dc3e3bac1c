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


def campaign(n: int) -> list[str]:
    return ["--airframe", "quadrotor", "--campaign", str(n), "--seed", "3", "--through",
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
    p = drill(*campaign(N), "--runs-dir", str(runs))
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


def _descendants(pid: int) -> list[int]:
    kids = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                ppid = int((d / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            kids.setdefault(ppid, []).append(int(d.name))
    out, todo = [], [pid]
    while todo:
        for k in kids.get(todo.pop(), []):
            out.append(k)
            todo.append(k)
    return out


def _running(pid: int) -> bool:
    """Is the process there and not a zombie (ended, its exit status not yet collected: an
    orphan's is collected by PID 1, which in a container may never do it)?"""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


@pytest.mark.slow
@pytest.mark.timeout(900)
@pytest.mark.parametrize("backend,sig,rc", [("process", "SIGTERM", 143), ("ray", "SIGINT", 130)])
def test_a_signal_stops_a_campaign_with_its_workers_and_resume_finishes_it(tmp_path, backend,
                                                                           sig, rc):  # fmt: skip
    """SIGTERM / SIGINT to a parallel campaign once it has rows: exit 128 + signum, no worker
    left, summary.md and the last line say how many drills are kept and how to go on; --resume
    then flies the rest, each drill once."""
    import signal
    import time

    from skyherd.runio.parallel import ray_available

    if backend == "ray" and not ray_available():
        pytest.skip("Ray not installed (pip install -e '.[ray]')")
    n, runs = 30, tmp_path / "runs"
    argv = [sys.executable, "-m", "skyherd.scripts.cli", "drill", *campaign(n),
            "--workers", "2", "--backend", backend, "--runs-dir", str(runs)]  # fmt: skip
    p = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and p.poll() is None:
            m = list(runs.glob("*/metrics.csv"))
            if m and len(m[0].read_text().splitlines()) >= 1 + 3:
                break
            time.sleep(0.05)
        assert p.poll() is None, "the campaign ended before it was signalled"
        kids = _descendants(p.pid)
        p.send_signal(getattr(signal, sig))
        out, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == rc, err[-2000:]
    (folder,) = runs.iterdir()
    assert f"go on with `skyherd drill --resume {folder}`" in err, err[-2000:]
    assert "INTERRUPTED" in (folder / "summary.md").read_text()
    deadline = time.monotonic() + 30  # Ray's own processes end once their driver is gone
    while time.monotonic() < deadline and any(_running(k) for k in kids):
        time.sleep(0.2)
    left = [k for k in kids if _running(k)]
    assert not left, [Path(f"/proc/{k}/cmdline").read_bytes()[:80] for k in left]
    kept = len(rows(folder))
    assert 3 <= kept < n
    q = drill("--resume", str(folder), "--workers", "2", "--backend", backend)
    assert q.returncode == 0, q.stderr[-2000:]
    assert f"{kept} drills judged before, {n - kept} to fly" in q.stdout
    got = rows(folder)
    assert len(got) == n == len({r["drill"] for r in got})
