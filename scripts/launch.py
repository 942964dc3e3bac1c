"""Child processes of `skyherd fly`: start `skyherd sim` and `skyherd companion`, watch them,
stop them in the right order, and say clearly which one ended the flight and why.

Rules: the companion ends the flight (its exit code is the flight's); a simulator that dies
first ends it too (the companion is stopped, its log tail shown); the wall-clock limit stops
both. The simulator is stopped after the companion (SIGINT, then SIGKILL after a grace period),
so the vehicle it simulates lands or disarms before it disappears.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path


@dataclass
class Child:
    name: str
    proc: subprocess.Popen
    log: Path | None

    def go(self) -> None:
        """Let a child started with `wait_go` begin (one line on its standard input)."""
        if self.proc.stdin is None or self.proc.stdin.closed:
            return
        try:
            self.proc.stdin.write(b"go\n")
            self.proc.stdin.close()
        except (BrokenPipeError, OSError):
            pass  # it ended already: supervise() reports how

    def tail(self, n: int = 5) -> str:
        if self.log is None or not self.log.exists():
            return ""
        lines = self.log.read_text(errors="replace").strip().splitlines()
        return "\n".join("    " + ln for ln in lines[-n:])


def skyherd_cmd(*args: str) -> list[str]:
    """A sub-command of this installation's `skyherd`, as a child process's argv."""
    return [sys.executable, "-m", "scripts.cli", *args]


def start(name: str, argv: list[str], log: Path | None, wait_go: bool = False) -> Child:
    """Start a child; its stdout and stderr go to `log` (None: inherited, e.g. a progress bar).
    `wait_go`: its standard input is a pipe that `go()` writes to (`skyherd companion
    --wait-go`), otherwise empty."""
    out = open(log, "ab") if log is not None else None  # noqa: SIM115 - closed with the child
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT if out else None,
                            stdin=subprocess.PIPE if wait_go else subprocess.DEVNULL, env=env)  # fmt: skip
    if out is not None:
        out.close()
    return Child(name, proc, log)


def stop(child: Child, grace_s: float = 10.0) -> int:
    """SIGINT, then SIGKILL after `grace_s`; returns the exit code."""
    return stop_all([child], grace_s)[0]


def stop_all(children: list[Child], grace_s: float = 10.0) -> list[int]:
    """SIGINT to every child at once, then wait for each; SIGKILL to any still running
    `grace_s` after the signal. K simulators end together, not one after another."""
    for c in children:
        if c.proc.poll() is None:
            c.proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace_s
    for c in children:
        try:
            c.proc.wait(max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            c.proc.kill()
            c.proc.wait()
    return [c.proc.returncode for c in children]


COMPANION_EXITED = "the companion exited with code"


def flight_reason(companion_reason: str | None, why: str) -> str:
    """Why the flight ended: the supervisor's reason when it stopped the companion (the time
    limit, a simulator that died), else the companion's own (it ended the flight)."""
    if why and not why.startswith(COMPANION_EXITED):
        return why
    return companion_reason or why


class Launch:
    """The children of one flight, stopped on every way out of `with Launch() as kids:` (the
    flight's end, an error, a Ctrl-C at any moment, the start-up included): the companion first,
    so that the vehicles it flies land or disarm, then every simulator at once."""

    def __init__(self) -> None:
        self.companion: Child | None = None
        self.sims: list[Child] = []

    def start_sim(self, name: str, argv: list[str], log: Path | None) -> Child:
        child = start(name, argv, log)
        self.sims.append(child)
        return child

    def start_companion(self, argv: list[str], log: Path | None = None,
                        wait_go: bool = False) -> Child:  # fmt: skip
        self.companion = start("companion", argv, log, wait_go)
        return self.companion

    def __enter__(self) -> Launch:
        return self

    def __exit__(self, *exc) -> None:
        try:  # a second Ctrl-C while the companion ends still stops the simulators
            if self.companion is not None:
                stop(self.companion)
        finally:
            stop_all(self.sims)

    def supervise(self, timeout_s: float) -> tuple[int, str]:
        """Wait for the flight to end; return (exit code, why it ended). The companion's end
        is the flight's; a simulator that dies first ends it too, and so does the wall-clock
        limit (the companion is stopped then, and its code is not the flight's)."""
        companion = self.companion
        deadline = time.monotonic() + timeout_s
        while True:
            rc = companion.proc.poll()
            if rc is not None:
                return rc, "" if rc == 0 else f"{COMPANION_EXITED} {rc}"
            for s in self.sims:
                if s.proc.poll() is not None:
                    why = f"the simulator {s.name} exited with code {s.proc.returncode} during the flight"
                    tail = s.tail()
                    stop(companion)
                    return 1, why + (f":\n{tail}" if tail else "")
            if time.monotonic() > deadline:
                stop(companion)
                return 1, f"the flight took longer than --timeout {timeout_s:.0f} s of wall time"
            time.sleep(0.02)  # a child's end is seen within 20 ms (it ends the flight)
