"""The ArduPilot JSON bridge's lockstep thread on one CPU (runio.pin), against the scripted
ArduPilot peer (hil.bridge_peers.ArduPilotJsonPeer) over real UDP; ArduCopter started by
hil.autopilot_sitl on the same CPU; `skyherd sim --pin-cpu` checked. Instances 86-89 (UDP
9862..9892)."""

from __future__ import annotations

import os
import threading

import pytest

from skyherd.hil import autopilot_sitl
from skyherd.hil.ardupilot_json import ArduPilotJsonBridge, json_port
from skyherd.hil.bridge_peers import ArduPilotJsonPeer
from skyherd.runio.pin import choose_cpu, cpu_list

FRAMES = 300
ALL = cpu_list(os.sched_getaffinity(0))


def _allowed_list_of(pid: int | str, tid: int) -> str:
    """Cpus_allowed_list of thread `tid` of process `pid`, as /proc shows it."""
    with open(f"/proc/{pid}/task/{tid}/status") as f:
        return next(ln.split(":", 1)[1].strip() for ln in f if ln.startswith("Cpus_allowed_list"))


def _allowed_list(tid: int) -> str:
    return _allowed_list_of("self", tid)


def _lockstep(bridge: ArduPilotJsonBridge) -> dict:
    """The bridge served in its own thread for FRAMES frames against the peer (this thread);
    the lockstep thread's and this thread's CPUs as /proc shows them in mid-run."""
    seen: dict = {}

    def look(b: ArduPilotJsonBridge) -> None:
        if b.stats.frames == FRAMES // 2:
            seen["lockstep"] = _allowed_list(threading.get_native_id())
            seen["peer"] = _allowed_list(threading.main_thread().native_id)

    th = threading.Thread(target=bridge.serve, kwargs={"max_frames": FRAMES, "idle_timeout_s": 20,
                                                       "on_step": look})  # fmt: skip
    th.start()
    peer = ArduPilotJsonPeer(bridge.port)
    try:
        replies = peer.run(FRAMES)
    finally:
        peer.close()
    th.join(30)
    assert not th.is_alive() and bridge.stats.frames == FRAMES and len(replies) == FRAMES
    return seen


def test_the_lockstep_thread_runs_on_the_chosen_cpu_and_nothing_else_does():
    expected = choose_cpu("auto", 87)
    with ArduPilotJsonBridge(instance=87) as b:  # opened here: this thread held first
        assert b.cpu == expected
        if expected is not None:
            assert _allowed_list(threading.get_native_id()) == str(expected)
        seen = _lockstep(b)
        assert b.stats.cpu == expected
    # serve() moved the pin to its own thread: the peer (this thread) kept every CPU
    assert seen == {"lockstep": ALL if expected is None else str(expected), "peer": ALL}
    assert _allowed_list(threading.get_native_id()) == ALL  # and close() let go


def test_off_and_two_instances_spread():
    with ArduPilotJsonBridge(instance=88, pin_cpu="off") as b:
        assert b.cpu is None and _lockstep(b) == {"lockstep": ALL, "peer": ALL}
        assert b.stats.cpu is None
    cpus = sorted(os.sched_getaffinity(0))
    if len(cpus) > 1:
        assert ArduPilotJsonBridge(instance=88).cpu != ArduPilotJsonBridge(instance=89).cpu


def test_a_cpu_not_allowed_is_refused_before_anything_binds():
    with pytest.raises(ValueError, match="--pin-cpu 4096: CPU 4096 is not one"):
        ArduPilotJsonBridge(instance=86, pin_cpu="4096")
    from skyherd.scripts.sim import check_args

    why = check_args(["--autopilot", "ardupilot", "--instance", "86", "--pin-cpu", "4096"])
    assert why is not None and "--pin-cpu 4096: CPU 4096 is not one" in why
    assert check_args(["--autopilot", "ardupilot", "--instance", "86", "--pin-cpu", "off"]) is None


def test_a_refused_pin_warns_once_and_the_lockstep_runs_unpinned(capfd):
    b = ArduPilotJsonBridge(instance=86)
    b.cpu = 4096  # a CPU the kernel refuses, as one outside a container's cpuset
    with b:
        seen = _lockstep(b)
    err = [ln for ln in capfd.readouterr().err.splitlines() if "pin" in ln]
    assert len(err) == 1 and err[0].startswith("skyherd: warning: cannot pin thread")
    assert err[0].endswith("running unpinned")
    assert seen == {"lockstep": ALL, "peer": ALL} and b.cpu is None and b.stats.cpu is None


def test_the_bridge_says_where_it_runs_once(capfd):
    with ArduPilotJsonBridge(instance=89, pin_cpu=str(max(os.sched_getaffinity(0)))) as b:
        _lockstep(b)
    said = [ln for ln in capfd.readouterr().err.splitlines() if "lockstep thread on CPU" in ln]
    assert said == [f"skyherd: ArduPilot JSON bridge (instance 89): lockstep thread on CPU "
                    f"{b.cpu} (--pin-cpu {b.cpu}; allowed {ALL}); run the autopilot on it too: "
                    f"taskset -c {b.cpu} arducopter ..."]  # fmt: skip


def test_arducopter_starts_on_its_bridge_s_cpu(tmp_path):
    """start_arducopter's child inherits the CPU for the moment of its start; the caller's
    thread gets its CPUs back. A script stands in for the binary (it reports its CPUs)."""
    fake = tmp_path / "arducopter"
    fake.write_text("#!/bin/sh\ngrep Cpus_allowed_list /proc/self/status\n")
    fake.chmod(0o755)
    for pin, expected in (("auto", choose_cpu("auto", 87)), ("off", None)):
        out = tmp_path / f"{pin}.log"
        with open(out, "wb") as log:
            proc = autopilot_sitl.start_arducopter(fake, 87, tmp_path, log, pin_cpu=pin)
            assert proc.wait(10) == 0
        got = out.read_text().split(":", 1)[1].strip()
        assert got == (ALL if expected is None else str(expected)), pin
        assert _allowed_list(threading.get_native_id()) == ALL


def test_skyherd_sim_pins_its_lockstep_thread_only(tmp_path):
    """`skyherd sim --autopilot ardupilot` (default --pin-cpu auto) against the scripted peer:
    in mid-run its main thread, the one that steps the lockstep, is on the chosen CPU, and the
    threads that were running before the bridge opened (Zenoh's runtime, the interpreter's) on
    every allowed CPU; the choice is said once and recorded in config.json and sim_stats.json.
    (Threads the lockstep thread starts itself later inherit its CPU: Zenoh's two shared-memory
    watchdogs, started with the camera's first frame.)"""
    import json
    import subprocess
    import sys

    instance, cpu = 88, choose_cpu("auto", 88)
    run = tmp_path / "run"
    run.mkdir()
    sim = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "sim", "--autopilot", "ardupilot",
         "--instance", str(instance), "--speedup", "0", "--runs-dir", str(run)],
        stdout=open(tmp_path / "sim.log", "wb"), stderr=subprocess.STDOUT,
    )  # fmt: skip
    peer = ArduPilotJsonPeer(json_port(instance))
    try:
        assert len(peer.run(FRAMES)) == FRAMES  # the first frames wait for the world to start
        tasks = {}
        for t in os.listdir(f"/proc/{sim.pid}/task"):
            with open(f"/proc/{sim.pid}/task/{t}/comm") as f:
                tasks[int(t)] = (f.read().strip(), _allowed_list_of(sim.pid, int(t)))
        assert len(peer.run(FRAMES)) == 2 * FRAMES  # (all its replies so far)
    finally:
        peer.close()
        sim.terminate()
        assert sim.wait(60) == 0, (tmp_path / "sim.log").read_text()[-2000:]
    assert tasks.pop(sim.pid)[1] == (ALL if cpu is None else str(cpu))
    zenoh = {name for name, _ in tasks.values()} & {"app-0", "net-0", "acc-0"}
    assert zenoh and {cpus for name, cpus in tasks.values() if not name.startswith("Watchdog")} == {
        ALL
    }
    said = [
        ln for ln in (tmp_path / "sim.log").read_text().splitlines() if "lockstep thread on" in ln
    ]
    assert len(said) == (0 if cpu is None else 1)
    (folder,) = run.iterdir()
    stats = json.loads((folder / "sim_stats.json").read_text())
    assert stats["bridge"].endswith(f"cpu={cpu})")
    assert json.loads((folder / "config.json").read_text())["args"]["pin_cpu"] == "auto"
