"""`skyherd fly`: the main job end to end — `skyherd sim` and `skyherd companion` as two child
processes in lockstep, MAVLink and Zenoh over loopback. Lockstep makes the flights independent
of the machine's load, so they run as fast as possible (--speedup 0)."""

import csv
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from skyherd.record import read_messages
from skyherd.scripts.cli import main


@pytest.mark.slow
def test_fly_square_end_to_end(tmp_path, capsys):
    args = ["fly", "--mission", "square", "--speedup", "0", "--timeout", "600",
            "--instance", "14", "--zenoh-port", "7455", "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    assert {"config.json", "telemetry.tlog", "metrics.csv", "track.png", "summary.md"} <= {
        p.name for p in run.iterdir()
    }
    assert "completed" in (run / "summary.md").read_text()
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    pos = np.array([[float(r["north"]), float(r["east"]), float(r["down"])] for r in rows])
    # it reached 20 m, visited every corner of the 40 m square, and came back down
    assert 19.0 < -pos[:, 2].min() < 21.5
    for corner in ([40, 0], [40, 40], [0, 40], [0, 0]):
        assert np.min(np.linalg.norm(pos[:, :2] - corner, axis=1)) < 1.0
    assert -pos[-1, 2] < 0.3
    # the tlog is a real MAVLink log: pymavlink reads our heartbeats and the vehicle's
    log = mavutil.mavlink_connection(str(run / "telemetry.tlog"))
    seen = set()
    while (m := log.recv_match()) is not None:
        seen.add((m.get_type(), m.get_srcSystem()))
    assert {("HEARTBEAT", 15), ("LOCAL_POSITION_NED", 15), ("COMMAND_ACK", 15)} <= seen
    assert ("SET_POSITION_TARGET_LOCAL_NED", 15) in seen  # the companion: system 1+N, comp 191


def test_fly_bad_usage_exits_2(tmp_path, capsys):
    assert (
        main(["fly", "--mission", "square", "--altitude", "500", "--runs-dir", str(tmp_path)]) == 2
    )
    assert main(["fly", "--speedup", "0.5", "--runs-dir", str(tmp_path)]) == 2
    assert main(["fly", "--connect", "bogus", "--runs-dir", str(tmp_path)]) == 2
    assert "'bogus' is not an address; give tcp:HOST:PORT" in capsys.readouterr().err
    assert not any(tmp_path.iterdir())


@pytest.mark.slow
def test_fly_groundair_policy_keeps_the_team_in_view(tmp_path, capsys):
    """The main job: the kept policy flies through MAVLink offboard behind the safety net."""
    args = ["fly", "--duration", "30", "--speedup", "0", "--timeout", "600", "--zenoh-port",
            "7456", "--instance", "15", "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    names = {p.name for p in run.iterdir()}
    assert {"config.json", "telemetry.tlog", "metrics.csv", "events.jsonl", "groundair.png",
            "frames.png", "summary.md"} <= names  # fmt: skip
    cfg = json.loads((run / "config.json").read_text())
    assert cfg["envelope"]["name"] == "quadrotor-groundair" and cfg["envelope"]["version"]
    summary = (run / "summary.md").read_text()
    frac = float(re.search(r"all UGVs in view \[fraction of decisions\] \| ([0-9.]+)", summary)[1])
    decisions = int(re.search(r"decisions +\| (\d+)", summary)[1])
    assert decisions >= 55  # one every 0.5 s for 30 s
    assert frac >= 0.9, summary
    # the judge (safety/judge.py; tests/e2e/test_fly_judge.py): every check passed
    judged = re.findall(r"^\| (\w+) +\| (pass|FAIL) +\|", summary, re.M)
    assert [c for c, _ in judged] == ["fence", "armed", "modes", "camera", "end", "mission"]
    assert {r for _, r in judged} == {"pass"}, summary
    modes = [json.loads(x) for x in (run / "modes.jsonl").read_text().splitlines()]
    assert [(m["mode"], m["armed"]) for m in modes][:3] == [("HOLD", False), ("HOLD", True),
                                                            ("TAKEOFF", True)]  # fmt: skip
    assert not any(m["by_companion"] is False for m in modes)  # every change in order, all asked
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    modes = {r["mode"] for r in rows}
    assert "OFFBOARD" in modes and float(rows[-1]["down"]) > -0.3  # flew offboard, landed
    # flight.mcap, recorded from the Zenoh keys by a third process-side session (record/)
    rec = read_messages(run / "flight.mcap")
    counts = rec.counts()
    recorded = (run / "decisions.jsonl").read_text().splitlines()  # the landing's descent too
    assert sum('"pilot": "policy"' in x for x in recorded) == decisions
    assert rec.complete and counts["/uav0/decision"] == len(recorded)
    frames = sum(1 for _ in open(run / "world.csv")) - 1
    assert (
        counts["/uav0/camera/image"] >= 0.9 * frames and counts["/ugvs"] >= 0.9 * frames
    )  # a scene of all UGVs a frame


def test_companion_waiting_for_its_go_ends_cleanly_when_standard_input_closes(tmp_path):
    """`skyherd companion --wait-go` (as `fly` starts it) whose parent is gone: it says why and
    writes its run folder, without a word to the vehicle."""
    r = subprocess.run([sys.executable, "-m", "skyherd.scripts.cli", "companion", "--mission", "square",
                        "--no-camera", "--wait-go", "--instance", "62", "--runs-dir", str(tmp_path)],
                       stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 1, r.stderr
    (run,) = tmp_path.iterdir()
    comp = json.loads((run / "companion.json").read_text())
    assert comp["outcome"] == "aborted" and "--wait-go: standard input closed" in comp["reason"]
    assert comp["ticks"] == 0


@pytest.mark.parametrize("after_s", [0.4, 1.0, 2.0])
@pytest.mark.slow
def test_fly_interrupted_while_starting_stops_both_children_wall_time(tmp_path, after_s):
    """Ctrl-C to `skyherd fly` alone, at a moment of wall time (before, while or after the
    recorder starts and the companion sets up: which one depends on the machine's load): it
    ends interrupted and neither child outlives it."""
    import signal
    import time

    p = subprocess.Popen([sys.executable, "-m", "skyherd.scripts.cli", "fly", "--speedup", "0",
                          "--instance", "63", "--zenoh-port", "7473", "--runs-dir", str(tmp_path)],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    time.sleep(after_s)
    p.send_signal(signal.SIGINT)
    # 130; or 1 / −SIGINT when the signal came before `main` began (the interpreter's start-up)
    assert p.wait(timeout=120) in (130, 1, -signal.SIGINT)
    left = _children_of_instance(63)
    for pid in left:  # (stopped, so that a failure here leaves nothing behind either)
        os.kill(pid, signal.SIGKILL)
    assert left == []


def _children_of_instance(n: int) -> list[int]:
    """PIDs of `skyherd sim` / `skyherd companion` processes of instance n (from /proc)."""
    found = []
    for d in Path("/proc").iterdir():
        try:
            argv = (d / "cmdline").read_bytes().split(b"\0")
        except OSError:  # not a process, or it ended meanwhile
            continue
        if (
            b"skyherd.scripts.cli" in argv
            and {b"sim", b"companion"} & set(argv)
            and b"--instance" in argv
        ):
            if argv[argv.index(b"--instance") + 1] == str(n).encode():
                found.append(int(d.name))
    return found


_CHILD = """
import signal, sys, time
def on_int(signum, _):
    name = signal.Signals(signum).name.lower()
    open(sys.argv[1], "a").write(f"{sys.argv[2]} {name} {time.monotonic()}\\n")
    time.sleep(float(sys.argv[3]))  # what it takes to land / to close its files
    open(sys.argv[1], "a").write(f"{sys.argv[2]} ended {time.monotonic()}\\n")
    sys.exit(0)
signal.signal(signal.SIGINT, on_int)
signal.signal(signal.SIGUSR1, on_int)  # a simulator's "your companion is gone"
open(sys.argv[1], "a").write(f"{sys.argv[2]} ready {time.monotonic()}\\n")
while True:
    time.sleep(0.01)
"""


def test_a_launch_stops_the_companion_first_then_every_simulator_on_a_ctrl_c(tmp_path):
    """`runio.launch.Launch` on a KeyboardInterrupt inside its `with` (a Ctrl-C while the
    children start or fly): the companion gets SIGINT and is waited for (it hands the
    vehicles to their autopilots) before the simulators get SIGUSR1 (they wind down alone with
    the autopilot); none is left running. Ordered by the log the children write, not by a
    clock's margin."""
    from skyherd.runio import launch

    log = tmp_path / "order.log"
    ready = lambda: log.read_text().count("ready") if log.exists() else 0  # noqa: E731
    kids = None
    with pytest.raises(KeyboardInterrupt):
        with launch.Launch() as kids:
            for name in ("sim0", "sim1"):
                kids.start_sim(name, [sys.executable, "-c", _CHILD, str(log), name, "0"], None)
            kids.start_companion([sys.executable, "-c", _CHILD, str(log), "companion", "0.3"])
            while ready() < 3:
                assert all(c.proc.poll() is None for c in (kids.companion, *kids.sims))
                time.sleep(0.01)
            raise KeyboardInterrupt
    assert all(c.proc.poll() == 0 for c in (kids.companion, *kids.sims))
    lines = [ln.split()[:2] for ln in log.read_text().splitlines() if "ready" not in ln]
    assert lines[:2] == [["companion", "sigint"], ["companion", "ended"]]
    assert sorted(lines[2:]) == [["sim0", "ended"], ["sim0", "sigusr1"], ["sim1", "ended"],
                                 ["sim1", "sigusr1"]]  # fmt: skip


def test_fly_groundair_bad_policy_file_exits_2(tmp_path, capsys):
    bad = tmp_path / "policy.npz"
    bad.write_bytes(b"not a policy")
    assert main(["fly", "--policy", str(bad), "--runs-dir", str(tmp_path / "runs")]) == 2
    assert "not a readable skyherd policy" in capsys.readouterr().err


@pytest.mark.slow
def test_fly_pid_follower_over_a_groundsim_route(tmp_path, capsys):
    """Issue 4's flight: UGVs drive a groundsim route, a classic PID follower on φ flies."""
    args = ["fly", "--pilot", "pid", "--ugvs", "groundsim:route", "--duration", "25",
            "--speedup", "0", "--timeout", "600", "--instance", "16", "--zenoh-port", "7457",
            "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 0
    (run,) = tmp_path.iterdir()
    summary = (run / "summary.md").read_text()
    assert "pilot `pid`" in summary and "groundsim:route" in summary
    frac = float(re.search(r"all UGVs in view \[fraction of decisions\] \| ([0-9.]+)", summary)[1])
    assert frac >= 0.9, summary
    # the judge (safety/judge.py; tests/e2e/test_fly_judge.py): every check passed
    judged = re.findall(r"^\| (\w+) +\| (pass|FAIL) +\|", summary, re.M)
    assert [c for c, _ in judged] == ["fence", "armed", "modes", "camera", "end", "mission"]
    assert {r for _, r in judged} == {"pass"}, summary
    modes = [json.loads(x) for x in (run / "modes.jsonl").read_text().splitlines()]
    assert [(m["mode"], m["armed"]) for m in modes][:3] == [("HOLD", False), ("HOLD", True),
                                                            ("TAKEOFF", True)]  # fmt: skip
    assert not any(m["by_companion"] is False for m in modes)  # every change in order, all asked
    assert main(["fly", "--ugvs", "nowhere", "--runs-dir", str(tmp_path)]) == 2


@pytest.mark.slow
def test_fly_refuses_to_take_off_when_the_autopilot_disagrees_with_the_envelope(tmp_path, capsys):
    """Envelope ↔ autopilot: an offboard-loss timeout of 3 s (in range, settable by any client)
    lets a cut link run the vehicle far past the envelope's 0.3 s reaction: no take-off."""
    args = ["fly", "--param", "COM_OF_LOSS_T=3", "--duration", "5", "--speedup", "0",
            "--instance", "15", "--zenoh-port", "7456", "--runs-dir", str(tmp_path)]  # fmt: skip
    assert main(args) == 1
    (run,) = tmp_path.iterdir()
    summary = (run / "summary.md").read_text()
    assert "COM_OF_LOSS_T = 3 s" in summary and "refusing to take off" in summary
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    assert rows and not any(int(r["armed"]) for r in rows)  # never armed
    events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
    assert any(e.get("event") == "params" and not e["consistent"] for e in events)
