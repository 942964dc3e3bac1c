"""`skyherd drill --campaign N --workers 2 --backend process|ray` (runio.parallel): the drills run
in worker processes or as Ray tasks on a local instance (loopback only); one worker is killed
(SIGKILL) while the campaign runs, and every drill is still judged exactly once, each row the
same as the single-process campaign's of the same seed (a drill is a pure function of its
airframe, index and seed). Results are streamed: metrics.csv grows as drills finish."""

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from skyherd.runio.parallel import JobLost, map_unordered, ray_available

ROOT = Path(__file__).resolve().parents[2]
N = 24
KEY = ("drill", "kind", "passed", "failed_check", "min_clearance_m", "switches")


def _rows(runs: Path) -> list[dict]:
    (run,) = runs.iterdir()
    with open(run / "metrics.csv") as f:
        return list(csv.DictReader(f))


def _campaign(runs: Path, *extra: str) -> subprocess.Popen:
    argv = [sys.executable, "-m", "skyherd.scripts.cli", "drill", "--airframe", "quadrotor", "--campaign",
            str(N), "--seed", "5", "--no-plots", "--runs-dir", str(runs), *extra]  # fmt: skip
    return subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))  # fmt: skip


def _procs():
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                stat = (d / "stat").read_text()
                cmd = (d / "cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            except OSError:
                continue
            yield int(d.name), int(stat.rsplit(")", 1)[1].split()[1]), cmd


def _worker(backend: str, parent: int) -> int | None:
    """A worker busy with a drill: a child of the campaign (pool) or Ray's `ray::run_one`
    under it (its local instance's raylet is the campaign's child): never another campaign's."""
    procs = {pid: (ppid, cmd) for pid, ppid, cmd in _procs()}

    def under(pid: int) -> bool:
        while pid in procs and pid > 1:
            pid = procs[pid][0]
            if pid == parent:
                return True
        return False

    for pid, (ppid, cmd) in procs.items():
        if backend == "process" and ppid == parent:
            return pid
        if backend == "ray" and cmd.startswith("ray::run_one") and under(pid):
            return pid
    return None


@pytest.fixture(scope="module")
def reference(tmp_path_factory) -> dict[str, tuple]:
    runs = tmp_path_factory.mktemp("serial")
    p = _campaign(runs)
    p.communicate(timeout=900)
    rows = _rows(runs)
    assert len(rows) == N
    return {r["drill"]: tuple(r[k] for k in KEY) for r in rows}


@pytest.mark.parametrize("backend", ["process", "ray"])
@pytest.mark.slow
@pytest.mark.timeout(1800)  # its own waits allow 600 s + 900 s (Ray's start-up under load)
def test_a_killed_worker_loses_no_drill_and_changes_no_row(backend, reference, tmp_path):
    if backend == "ray" and not ray_available():
        pytest.skip("Ray not installed (pip install -e '.[ray]')")
    runs = tmp_path / "runs"
    p = _campaign(runs, "--workers", "2", "--backend", backend)
    killed = None
    try:
        deadline = time.monotonic() + 600
        while killed is None and p.poll() is None and time.monotonic() < deadline:
            started = any(runs.glob("*/metrics.csv")) and len(_rows(runs)) >= 1
            pid = _worker(backend, p.pid) if started else None
            if pid is not None:
                os.kill(pid, signal.SIGKILL)
                killed = pid
            time.sleep(0.05)
        out, err = p.communicate(timeout=900)
    finally:
        if p.poll() is None:
            p.kill()
    assert killed is not None, "no worker was seen busy: the campaign ended first"
    assert p.returncode == 0, err[-2000:]
    rows = _rows(runs)
    assert len(rows) == N and len({r["drill"] for r in rows}) == N  # each drill exactly once
    assert {r["drill"]: tuple(r[k] for k in KEY) for r in rows} == reference


def _die_once(job):
    """A job whose first run kills its worker (the marker file says it has run)."""
    marker, value = job
    if value == 3 and not os.path.exists(marker):
        open(marker, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return value * value


def _die_always(job):
    os.kill(os.getpid(), signal.SIGKILL)


def test_the_pool_reruns_what_a_dead_worker_left_and_gives_up_after_the_retries(tmp_path):
    marker = str(tmp_path / "died")
    jobs = [(marker, v) for v in range(8)]
    got = dict(map_unordered(_die_once, jobs, "process", workers=2, say=lambda s: None))
    assert os.path.exists(marker) and got == {(marker, v): v * v for v in range(8)}
    with pytest.raises(JobLost):
        list(map_unordered(_die_always, [1], "process", workers=1, retries=2, say=lambda s: None))


def _die_once_at(job):
    """Job `die` of many kills its worker the first time it runs."""
    marker, value, die = job
    if value == die and not os.path.exists(marker):
        open(marker, "w").close()
        os.kill(os.getpid(), signal.SIGKILL)
    return os.getpid(), value * value


@pytest.mark.parametrize(
    "die", [0, 1_777, 2_999]
)  # the first, one inside the window's run, the last
def test_many_jobs_in_a_window_each_exactly_once_across_a_dead_worker(tmp_path, die):
    """Thousands of jobs (a campaign's scale: handed out a window at a time, runio.parallel
    IN_FLIGHT_PER_WORKER): every result once, the dead worker's jobs again on a new pool."""
    marker = str(tmp_path / "died")
    jobs = [(marker, v, die) for v in range(3_000)]
    said = []
    got = list(map_unordered(_die_once_at, jobs, "process", workers=2, say=said.append))
    assert os.path.exists(marker)
    assert sorted(j[1] for j, _ in got) == list(range(3_000))  # each once
    assert all(r[1] == j[1] ** 2 for j, r in got)
    assert len(said) == 1 and "run again on a new pool" in said[0], said
    assert len({r[0] for _, r in got}) >= 2  # more than one worker process did the work
