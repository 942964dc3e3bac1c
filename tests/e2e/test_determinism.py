"""Lockstep's test: the same seed gives the same run folder (trajectory, decisions, events,
metrics; wall-time stamps aside) at any speed-up and with the machine busy.

Each flight is `skyherd fly` as a user runs it: the simulator and the companion as two child
processes on Zenoh and MAVLink over loopback. Two `yes > /dev/null` processes compete for the
2 cores in the busy runs; the formation is K = 9 simulators and one companion. The full matrix
(1×, 10×, as fast as possible, formation, orbit) is
bench/bench_lockstep.py's, with its hashes in docs/topology.md.
"""

import hashlib
import subprocess

import pytest

from skyherd.scripts.cli import main

COMPARED = ("decisions.jsonl", "world.csv", "metrics.csv", "events.jsonl")


def digest(run) -> dict[str, str]:
    """SHA-256 of the compared files, and of each formation vehicle's world.csv (uav<k>/)."""
    names = [n for n in COMPARED if (run / n).exists()]
    names += sorted(str(p.relative_to(run)) for p in run.glob("uav*/world.csv"))
    return {n: hashlib.sha256((run / n).read_bytes()).hexdigest()[:16] for n in names}


def fly(tmp_path, name, args, busy=False):
    out = tmp_path / name
    hogs = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(2 if busy else 0)]
    try:
        assert main(["fly", *args, "--runs-dir", str(out), "--timeout", "900"]) == 0
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    (run,) = out.iterdir()
    return run


@pytest.mark.slow
@pytest.mark.timeout(1800)  # only stops a hung run: lockstep flights take what the machine gives
@pytest.mark.parametrize(
    "mission,args,runs",
    [
        ("groundair", ["--duration", "6", "--instance", "12", "--zenoh-port", "7453"],
         [("0", False), ("10", False), ("0", True)]),
        ("square", ["--mission", "square", "--side", "8", "--altitude", "4", "--instance", "13",
                    "--zenoh-port", "7454"], [("0", False), ("10", True)]),
        ("formation", ["--mission", "formation", "--agents", "9", "--instance", "180"],
         [("0", False), ("10", True)]),
        ("orbit", ["--airframe", "fixedwing", "--orbit-duration", "10", "--orbit-no-land",
                   "--instance", "14", "--zenoh-port", "7455"], [("0", False), ("10", True)]),
    ],
)  # fmt: skip
def test_same_seed_same_flight_at_any_speedup_and_load(tmp_path, mission, args, runs):
    if mission == "formation":  # K = 9 from the study's start cells, 6 cells north in lock-step
        import json

        from skyherd.policy.sql.layout import STARTS

        plan = tmp_path / "plan_K9.json"
        plan.write_text(json.dumps([[[x, y + i] for i in range(7)] for x, y in STARTS[9]]))
        args = [*args, "--policy-file", str(plan)]
    digests = []
    for i, (speedup, busy) in enumerate(runs):
        run = fly(tmp_path, f"{mission}-{i}", [*args, "--speedup", speedup], busy)
        digests.append(digest(run))
        assert "completed" in (run / "summary.md").read_text()
    assert set(digests[0]) >= {"decisions.jsonl", "metrics.csv"}
    assert "world.csv" in digests[0] or len([n for n in digests[0] if n.startswith("uav")]) == 9
    for d, (speedup, busy) in zip(digests[1:], runs[1:]):
        assert d == digests[0], f"speed-up {speedup}{' busy' if busy else ''} differs"
