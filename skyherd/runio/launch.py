"""Child processes of `skyherd fly`: start `skyherd sim` and `skyherd companion`, watch them,
stop them in the right order, and say clearly which one ended the flight and why.

Rules: the companion ends the flight (its exit code is the flight's); a simulator that dies
first ends it too (the companion is stopped, its log tail shown); the wall-clock limit stops
both. Every way out (the flight's end, an error, SIGINT / SIGTERM / SIGHUP to `fly`) ends the
children in one order:

1. the companion gets SIGINT: it hands the vehicle to the autopilot (LAND, or the airframe's
   own landing mode) within a few ticks and exits; SIGKILL after `COMPANION_GRACE_S`;
2. each simulator gets SIGUSR1, "your companion is gone": it steps on alone, as fast as
   possible, until the autopilot has disarmed or `WorldParams.alone_s` of simulation time have
   passed (the autopilot's offboard-loss failsafe gets its simulation time), reports what the
   autopilot did in sim_stats.json and exits; SIGINT after `WIND_DOWN_S`, then SIGKILL.

A child gets SIGINT once its own handlers are in place: interrupted while its interpreter
starts it dies with "Fatal Python error: init_import_site" and a traceback on the terminal (seen
with a Ctrl-C 0.6 s into a flight); while numba loads a cached kernel the KeyboardInterrupt is
lost inside a ctypes callback and the flight flies on. Each child says on a pipe when its
handlers are in place (runio.signals.say_ready: the companion's mission.handover, the
simulator's world.serve) and `stop` waits for that, `READY_WAIT_S` at most.

A second signal to `fly` while this runs skips to stopping the simulators at once. Children
run in their own process group (a terminal's Ctrl-C reaches `fly` alone, which orders the
rest) and die with their parent: their parent-death signal is SIGUSR1 (the companion: hand
over, as on SIGINT; a simulator: its companion is gone, as above; the kernel may send it once
per thread of the dying parent, a repeat changes nothing), so a `kill -9` of `fly` still lands
the vehicle or leaves it in its failsafe, and leaves no process behind.
"""

from __future__ import annotations

import ctypes
import os
import select
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path

from skyherd.runio import process
from skyherd.runio.constants import READY_FD_ENV
from skyherd.runio.signals import KeptSignals
from skyherd.runio.space import Appender

KEEP_LINES = 200  # a child's last output lines kept in memory (its log may be cut)
COMPANION_GRACE_S = 30.0  # wall time for the companion's hand-over before SIGKILL [s]
WIND_DOWN_S = 120.0  # wall time for a simulator's span alone with the autopilot before SIGINT [s]
READY_WAIT_S = 10.0  # wall time a child may take to put its signal handlers in place [s]
CHILD_POLL_S = 0.02  # a child's end is seen within this [wall s] (it ends the flight)
PARENT_DEATH = signal.SIGUSR1  # every child's parent-death signal (module docstring)
PR_SET_PDEATHSIG = 1  # linux/prctl.h
CHILD_ENV = {"OPENBLAS_NUM_THREADS": "1"}
"""Every child's environment has these unless the user's has them: OpenBLAS with no worker
threads. The children's BLAS calls are on vectors of 3 to 8 elements, which OpenBLAS never
splits, but each OpenBLAS a process loads (numpy's, SciPy's) started a thread per core that spun
for a while: ~0.05 CPU s per library and process (numpy's import 0.12 → 0.07 CPU s, SciPy's
linalg 0.30 → 0.20; issue 31)."""


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: Path | None
    lines: deque | None = None  # its last output lines, kept in memory (`relay`)
    relay: threading.Thread | None = None
    ready_fd: int | None = None  # the pipe it says "I take signals" on (None: read, or none)
    ready: bool = False  # it has said so

    def wait_ready(self, wall_s: float) -> bool:
        """Wait up to `wall_s` until the child takes signals (its byte on the pipe, or the
        pipe closed: it ended, or never says it); True once it has said so."""
        if self.ready_fd is None:
            return self.ready
        if select.select([self.ready_fd], [], [], wall_s)[0]:
            self.ready = os.read(self.ready_fd, 1) == b"1"
            os.close(self.ready_fd)
            self.ready_fd = None
        return self.ready

    def go(self) -> None:
        """Let a child started with `wait_go` begin (one line on its standard input)."""
        if self.proc.stdin is None or self.proc.stdin.closed:
            return
        try:
            self.proc.stdin.write(b"go\n")
            self.proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass  # it ended already: supervise() reports how

    def said(self, prefix: str) -> bool:
        """Has the child written a line that begins with `prefix` (among its last lines)?"""
        return any(ln.startswith(prefix) for ln in list(self.lines or ()))

    def tail(self, n: int = 5) -> str:
        if self.relay is not None:
            self.relay.join(2.0)  # the child has ended: its last lines are on their way
        lines = list(self.lines or ())
        return "\n".join("    " + ln for ln in lines[-n:])


def relay(pipe, log: Path, lines: deque) -> None:
    """A child's output, line by line, to its log file (cut with a warning on a full disk or a
    read-only folder: runio.space) and to `lines` in memory, until the child closes it."""
    out = Appender(log)
    try:
        for raw in iter(pipe.readline, b""):
            out.write(raw)
            lines.append(raw.decode(errors="replace").rstrip("\n"))
    finally:
        out.close()
        pipe.close()


def die_with_parent(sig: int):
    """A `preexec_fn` that sets the child's parent-death signal to `sig` (Linux prctl
    PR_SET_PDEATHSIG) between fork and exec; a child whose parent died before that exits at
    once (its parent is no longer the one that forked it). None where there is no prctl."""
    if not sys.platform.startswith("linux"):
        return None
    prctl = ctypes.CDLL(None, use_errno=True).prctl  # looked up here, not in the forked child
    parent = os.getpid()

    def preexec() -> None:
        prctl(PR_SET_PDEATHSIG, int(sig), 0, 0, 0)
        if os.getppid() != parent:
            os._exit(128 + int(sig))

    return preexec


def start(name: str, argv: list[str], log: Path | None, wait_go: bool = False,
          parent_death: int | None = None, says_ready: bool = False) -> Child:  # fmt: skip
    """Start a child; its stdout and stderr go to `log` through this process (a pipe and a
    relay thread; the last lines kept in memory), or with `log` None are inherited (a
    progress bar).
    `wait_go`: its standard input is a pipe that `go()` writes to (`skyherd companion
    --wait-go`), otherwise empty. `parent_death`: the signal it gets if this process dies.
    `says_ready`: `skyherd sim` or `skyherd companion`, which say on a pipe when they take
    signals (module docstring). It runs in its own process group: a terminal's Ctrl-C reaches
    only this process."""
    env = {**CHILD_ENV, **os.environ, "PYTHONUNBUFFERED": "1"}
    pre = die_with_parent(parent_death) if parent_death is not None else None
    piped = subprocess.PIPE if log is not None else None
    ready_r, ready_w = os.pipe() if says_ready else (None, None)
    if says_ready:
        env[READY_FD_ENV] = str(ready_w)
    try:
        proc = subprocess.Popen(argv, stdout=piped, stderr=subprocess.STDOUT if piped else None,
                                stdin=subprocess.PIPE if wait_go else subprocess.DEVNULL, env=env,
                                process_group=0, preexec_fn=pre,
                                pass_fds=(ready_w,) if says_ready else ())  # fmt: skip
    finally:
        if says_ready:
            os.close(ready_w)
    child = Child(name, proc, log, ready_fd=ready_r)
    if log is not None:  # through this process: kept in memory when the folder fails
        child.lines = deque(maxlen=KEEP_LINES)
        child.relay = threading.Thread(target=relay, args=(proc.stdout, log, child.lines),
                                       name=f"relay-{name}", daemon=True)  # fmt: skip
        child.relay.start()
    return child


def stop(child: Child, grace_s: float = 10.0) -> int:
    """SIGINT, then SIGKILL after `grace_s`; returns the exit code."""
    return stop_all([child], grace_s)[0]


def signal_and_wait(children: list[Child], sig: int, wall_s: float) -> list[Child]:
    """`sig` to every child still running at once, then wait up to `wall_s` for them all;
    returns those still running. SIGINT goes to a child once it takes signals (`wait_ready`)."""
    deadline = time.monotonic() + wall_s
    for c in children:
        if sig == signal.SIGINT:  # (one that has ended: its pipe is closed, no wait)
            c.wait_ready(min(READY_WAIT_S, max(0.0, deadline - time.monotonic())))
        if c.proc.poll() is None:
            c.proc.send_signal(sig)
    late = []
    for c in children:
        try:
            c.proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            late.append(c)
    return late


def wind_down(sims: list[Child], wall_s: float = WIND_DOWN_S) -> None:
    """SIGUSR1 to every simulator still running ("your companion is gone": it steps on alone
    until the autopilot disarms or its `alone_s` has passed, then exits); wait up to `wall_s`
    (stop_all ends those still running)."""
    signal_and_wait(sims, signal.SIGUSR1, wall_s)


def stop_all(children: list[Child], grace_s: float = 10.0) -> list[int]:
    """SIGINT to every child at once, then wait for each; SIGKILL to any still running
    `grace_s` after the signal. K simulators end together, not one after another."""
    for c in signal_and_wait(children, signal.SIGINT, grace_s):
        c.proc.kill()
        c.proc.wait()
    return [c.proc.returncode for c in children]


def exit_text(rc: int) -> str:
    """A child's exit code as words: "code 1", "code -9 (killed by SIGKILL)"."""
    if rc < 0:
        try:
            return f"code {rc} (killed by {signal.Signals(-rc).name})"
        except ValueError:
            pass
    return f"code {rc}"


def say(text: str) -> None:
    """A line of `fly`'s on stderr at once (a child's end: seen within 20 ms, said now, not
    after the companion's hand-over and the report); never raises (runio.process.say)."""
    process.say(f"skyherd fly: {text}")


class Launch:
    """The children of one flight, stopped on every way out of `with Launch() as kids:` (the
    flight's end, an error, SIGINT / SIGTERM / SIGHUP at any moment, the start-up included):
    the companion first, so that it hands the vehicles to their autopilots, then every
    simulator winds down alone with its autopilot (module docstring). A signal while the
    children start is kept (runio.signals.KeptSignals: never raised half-way through a start) and
    acted on when `supervise` begins; from then on SIGINT, SIGTERM and SIGHUP raise
    `Interrupted` (a KeyboardInterrupt naming the signal). `signals`: the caller's
    KeptSignals (`fly` keeps them from before its run folder is made), else its own."""

    def __init__(self, signals: KeptSignals | None = None) -> None:
        self.companion: Child | None = None
        self.sims: list[Child] = []
        self._own = signals is None
        self.signals = KeptSignals() if signals is None else signals

    def start_sim(self, name: str, argv: list[str], log: Path | None) -> Child:
        child = start(name, argv, log, parent_death=PARENT_DEATH, says_ready=True)
        self.sims.append(child)
        return child

    def start_companion(self, argv: list[str], log: Path | None = None,
                        wait_go: bool = False) -> Child:  # fmt: skip
        self.companion = start("companion", argv, log, wait_go, PARENT_DEATH, says_ready=True)
        return self.companion

    def __enter__(self) -> Launch:
        if self._own:
            self.signals.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self.signals.raising(act=False)
        try:  # a second signal while the companion or the simulators end: stop all at once
            if self.companion is not None:
                stop(self.companion, COMPANION_GRACE_S)
            wind_down(self.sims)
        finally:
            stop_all([c for c in (self.companion, *self.sims) if c is not None])
            if self._own:
                self.signals.__exit__(None, None, None)
            else:
                self.signals.keeping()  # the caller writes its report whole

    def ended(self) -> bool:
        """Has any child ended (supervise() then says which and why)?"""
        return any(c.proc.poll() is not None for c in (self.companion, *self.sims) if c is not None)

    def supervise(self, timeout_s: float) -> tuple[int, str]:
        """Wait for the flight to end; return (exit code, why it ended). The companion's end
        is the flight's; a simulator that dies first ends it too, and so does the wall-clock
        limit (the companion is stopped then, and its code is not the flight's)."""
        self.signals.raising()  # a signal kept while the children started: acted on now
        companion = self.companion
        deadline = time.monotonic() + timeout_s
        while True:
            rc = companion.proc.poll()
            if rc is not None:
                if rc != 0:  # its own last line is above (its output is this terminal's)
                    say(f"the companion exited with {exit_text(rc)}; stopping the flight")
                return rc, "" if rc == 0 else f"the companion exited with {exit_text(rc)}"
            for s in self.sims:
                if s.proc.poll() is not None:
                    why = f"the simulator {s.name} exited with {exit_text(s.proc.returncode)} during the flight"
                    tail = s.tail()
                    last = tail.splitlines()[-1].strip() if tail else "(no output)"
                    say(f"{why}: {last}; stopping the companion (log: {s.log})")
                    stop(companion, COMPANION_GRACE_S)
                    return 1, why + (f":\n{tail}" if tail else "")
            if time.monotonic() > deadline:
                stop(companion, COMPANION_GRACE_S)
                return 1, f"the flight took longer than --timeout {timeout_s:.0f} s of wall time"
            time.sleep(CHILD_POLL_S)
