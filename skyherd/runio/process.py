"""A child process's view of its parent: has the process that started it died?

`skyherd fly` starts its children with a parent-death signal (runio.launch); a child that gets
it, or that ends after its parent, asks `parent_gone(pid)` with the parent's pid it noted at
its start (`os.getppid()` then)."""

from __future__ import annotations

import os


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
