"""A child process's view of its parent: has the process that started it died? And how a
command's process ends once it has returned (`exit_now`).

`skyherd fly` starts its children with a parent-death signal (runio.launch); a child that gets
it, or that ends after its parent, asks `parent_gone(pid)` with the parent's pid it noted at
its start (`os.getppid()` then)."""

from __future__ import annotations

import atexit
import os
import sys
import threading
from typing import NoReturn


def parent_gone(parent_pid: int) -> bool:
    """The parent `parent_pid` of this process has died (or is dying: its main thread a zombie
    while its other threads end, and this process not yet handed to another parent)."""
    if os.getppid() != parent_pid:
        return True
    try:
        with open(f"/proc/{parent_pid}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


def exit_now(rc: int) -> NoReturn:
    """End the process with `rc` once a command has returned: the atexit handlers run and
    standard output and error are flushed, then the interpreter's teardown (freeing every
    module and object, numba's LLVM) is skipped. It cost 0.2-0.4 s of wall time per process
    at the end of every flight (measured), and nothing is left to write then: every run-folder
    file is closed by the command that opened it (the tlog, mcap, CSV and JSONL writers; their
    owners close them in `finally` or `with`). A non-daemon thread still running gets the normal
    exit, which waits for it. `atexit._run_exitfuncs` is CPython's own step of a normal exit
    (the handlers, last registered first)."""
    if any(t.is_alive() and not t.daemon for t in threading.enumerate()
           if t is not threading.main_thread()):  # fmt: skip
        sys.exit(rc)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: nothing more can be said
            pass
    os._exit(rc)


def say(text: str) -> None:
    """A line on stderr that never raises (stderr may be a file on a full disk or in a
    read-only folder: a vehicle or a companion must not stop for it)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
