"""The suite's isolation and the fixtures shared by more than one test file.

Isolation: every vehicle sends to UDP 14550 and instance 0 owns 14540/14580/7447, so a test must
not hear another skyherd on the machine (or be heard by it). Where the kernel lets us (root, or
CAP_SYS_ADMIN), the test session enters its own network namespace before any test runs: only
loopback, up, and every process the tests start inherits it. Under pytest-xdist (`-n 2`: make
test-fast) each worker is a session of its own and enters its own namespace, so two tests running
at once on the same fixed ports never meet; the controller, which runs no test, stays in the
machine's. SKYHERD_TEST_NETNS=0 keeps the machine's namespace (the header says which one the
session runs in).
"""

import ctypes
import dataclasses
import fcntl
import os
import resource
import socket
import struct

import numpy as np
import pytest

from skyherd.safety.config import ENVELOPE_DIR, default_envelope_path, load_envelope
from skyherd.safety.envelope import circle_zone, polygon_zone

CLONE_NEWNET = 0x40000000  # <sched.h>
SIOCGIFFLAGS, SIOCSIFFLAGS, IFF_UP = 0x8913, 0x8914, 0x1  # <linux/sockios.h>, <net/if.h>


def _own_network_namespace() -> str:
    """Unshare the network namespace and bring loopback up; what happened, for the header."""
    if os.environ.get("SKYHERD_TEST_NETNS", "1") == "0":
        return "the machine's (SKYHERD_TEST_NETNS=0)"
    global MACHINE_NETNS_FD
    libc = ctypes.CDLL(None, use_errno=True)
    machine = os.open("/proc/self/ns/net", os.O_RDONLY)
    if libc.unshare(CLONE_NEWNET) != 0:
        os.close(machine)
        err = os.strerror(ctypes.get_errno())
        return f"the machine's (unshare: {err}; tests may meet other vehicles on 14550)"
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        ifreq = struct.pack("16sH22x", b"lo", 0)
        flags = struct.unpack("16sH22x", fcntl.ioctl(s, SIOCGIFFLAGS, ifreq))[1]
        fcntl.ioctl(s, SIOCSIFFLAGS, struct.pack("16sH22x", b"lo", flags | IFF_UP))
    os.environ["SKYHERD_TEST_NETNS"] = "0"  # a nested pytest (a test that runs pytest) stays here
    MACHINE_NETNS_FD = machine  # the machine's namespace, for tests/test_isolation.py
    return "its own (loopback only)"


MACHINE_NETNS_FD: int | None = None
NETWORK = "none yet"  # set by pytest_sessionstart, before collection


def _xdist_controller(config) -> bool:
    """This session hands its tests to pytest-xdist workers (each a session of its own)."""
    return config.pluginmanager.hasplugin("dsession")


def _workers_network_namespace(config) -> str:
    """The controller's header line: whether each worker can enter a namespace of its own (a
    forked child tries; this process stays in the machine's)."""
    workers = len(config.option.tx)
    if os.environ.get("SKYHERD_TEST_NETNS", "1") == "0":
        return f"the machine's (SKYHERD_TEST_NETNS=0), shared by the {workers} xdist workers"
    pid = os.fork()
    if pid == 0:
        libc = ctypes.CDLL(None, use_errno=True)
        os._exit(0 if libc.unshare(CLONE_NEWNET) == 0 else ctypes.get_errno() or 1)
    err = os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])
    if err:
        return (
            f"the machine's, shared by the {workers} xdist workers (unshare: {os.strerror(err)};"
            " tests may meet other vehicles on 14550 and each other: run without -n)"
        )
    return f"each of the {workers} xdist workers its own (loopback only)"


PR_SET_CHILD_SUBREAPER = 36  # <linux/prctl.h>: orphans of the tests' processes come back here
ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)  # (no_process_left)


def pytest_report_header(config):
    return f"skyherd: network namespace: {NETWORK}"


def pytest_sessionstart(session):
    """The network namespace (the module's docstring), then numba's kernels compiled (or loaded
    from their cache) before the first test, by one short in-process drill (the multirotor's
    physics, controller and mixer; the net's kernels) and a step of the bridges' body. A fresh
    clone has no cache: its first flight compiled them (about 10 s of CPU) inside a lockstep tick,
    where the peer's wall-clock patience runs (60 s), and under a load of 18 that first flight
    aborted ("no tick mark from the vehicle for 60 s"). Under pytest-xdist the controller fills
    the cache once, before it starts the workers (its own sessionstart runs last); they load it."""
    global NETWORK
    if _xdist_controller(session.config):
        NETWORK = _workers_network_namespace(session.config)
    else:
        NETWORK = _own_network_namespace()
    if hasattr(session.config, "workerinput"):  # an xdist worker: the controller warmed up
        return
    from skyherd.flight.multirotor import MultirotorAutopilot
    from skyherd.hil.bridge_physics import QuadBody
    from skyherd.safety.drills import DrillParams, run_drill, scripted_drills
    from skyherd.safety.supervisor import SupervisorParams

    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    p = DrillParams(duration_s=4.0)
    run_drill(scripted_drills(spec, p)[0], MultirotorAutopilot(), spec, SupervisorParams(), p)
    QuadBody().step(0.01, np.full(4, 0.5))


NORTH_35 = 35.0  # the judge tests' fence: its north edge [m]


@pytest.fixture(scope="session")
def north35_spec():
    """The ground-air envelope with its fence's north edge at 35 m and a 10 m tower exclusion
    100 m east: the judge's hand-made tracks (test_safety_judge.py, test_drill_judge.py)."""
    base, _ = load_envelope(ENVELOPE_DIR / "quadrotor_groundair.toml")
    n = NORTH_35
    fence = polygon_zone("north 35", [[-200, -200], [n, -200], [n, 200], [-200, 200]])
    tower = circle_zone("tower", np.array([0.0, 100.0]), 10.0, 16, True)
    return dataclasses.replace(base, inclusions=(fence,), exclusions=(tower,))


# -- no test leaves a process behind -------------------------------------------------------------
# A session (each xdist worker is one) runs its tests one after another in its own network
# namespace, and tests reuse vehicle instances (instance N's ports are reused by a later test, and N+40's client port is N's API port:
# CONVENTIONS.md). That is safe only while nothing a test started outlives it: a vehicle left
# running would be heard by the next test on those ports. So every test ends with none of the
# processes it started still alive (a grace for ones already on their way out); what is left is
# killed and the test fails naming it. SKYHERD_TEST_LEFTOVERS=report only prints them. The session
# is its processes' subreaper, so an orphan (its parent killed) is still found here.
LEFTOVER_GRACE_S = 20.0  # [wall s] for a process to finish its own exit (load: margin)


def _descendants() -> dict[int, str]:
    """This process's live descendants: pid -> command line."""
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat", "rb") as f:
                stat = f.read()
        except OSError:
            continue
        fields = stat[stat.rindex(b")") + 2 :].split()
        if fields[0] == b"Z":  # a zombie is dead: only its exit status is left to reap
            continue
        children.setdefault(int(fields[1]), []).append(int(d))
    out, todo = {}, [os.getpid()]
    while todo:
        for pid in children.get(todo.pop(), []):
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as f:
                    out[pid] = f.read().replace(b"\0", b" ").decode(errors="replace").strip()
            except OSError:
                continue
            todo.append(pid)
    return out


@pytest.fixture(autouse=True)
def no_process_left():
    before = set(_descendants())
    yield
    import time

    deadline = time.monotonic() + LEFTOVER_GRACE_S
    left = {p: c for p, c in _descendants().items() if p not in before}
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = {p: c for p, c in _descendants().items() if p not in before}
    if not left:
        return
    import signal

    for pid in left:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    what = "; ".join(f"{p}: {c[:160]}" for p, c in sorted(left.items()))
    if os.environ.get("SKYHERD_TEST_LEFTOVERS") == "report":
        print(f"\nleft running after the test (killed): {what}")
    else:
        pytest.fail(f"{len(left)} process(es) left running after the test (killed): {what}")


# -- a test left in the fast suite stays fast ----------------------------------------------------
# `make test-fast` leaves out the tests marked slow (3 CPU s or more each: pyproject's marker;
# the line was 10 s of wall time on 2 cores). Wall time says
# nothing on a loaded machine, but the CPU a test spends (this process and the children it
# reaped: flights, learners, subprocesses of skyherd) is nearly the same under load. An unmarked
# test that spends more than FAST_CPU_BUDGET_S from its setup to its teardown fails there, naming
# its CPU: mark it slow. The budget is 3× that 10 s line (a test may keep both cores busy; a loaded
# machine's shared caches add some CPU time). Only reaped children count: waiting costs nothing.
FAST_CPU_BUDGET_S = 30.0  # [CPU s]


_CPU_AT_START = pytest.StashKey[float]()


def _cpu_s() -> float:
    """CPU seconds of this process and of its children reaped so far."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    reaped = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + reaped.ru_utime + reaped.ru_stime


@pytest.hookimpl(tryfirst=True)
def pytest_runtest_setup(item):
    item.stash[_CPU_AT_START] = _cpu_s()


@pytest.hookimpl(wrapper=True)
def pytest_runtest_makereport(item, call):
    report = yield
    exempt = item.get_closest_marker("slow") or item.get_closest_marker("autopilot")
    if call.when != "teardown" or exempt or not report.passed or _CPU_AT_START not in item.stash:
        return report
    spent = _cpu_s() - item.stash[_CPU_AT_START]
    if spent > FAST_CPU_BUDGET_S:
        report.outcome = "failed"
        report.longrepr = (
            f"{item.nodeid} spent {spent:.1f} CPU s from setup to teardown, over the fast "
            f"suite's {FAST_CPU_BUDGET_S:g} per test: mark it @pytest.mark.slow"
        )
    return report
