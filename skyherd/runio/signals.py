"""The signals that end a run (SIGINT, SIGTERM, SIGHUP), taken without being raised where they
land: `KeptSignals` (`skyherd fly` while it makes its run folder and starts its children) and
`CtrlC` (`skyherd watch` from before its Zenoh session opens until its run folder is written);
`interrupted` turns the KeyboardInterrupt that ends a run into its exit code and words."""

from __future__ import annotations

import os
import signal

from skyherd.runio.constants import READY_FD_ENV
from skyherd.runio.run import Interrupted

INTERRUPTS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)  # the ways a user ends `fly`


class KeptSignals:
    """SIGINT, SIGTERM and SIGHUP kept, not raised, while `fly` makes its run folder and starts
    its children (an exception raised half-way through a fork, a pipe or a relay thread would
    leave a child no one stops, or a folder no one ends): `act()` then raises
    runio.Interrupted (a KeyboardInterrupt naming the signal) for the first one kept, and from
    `raising()` on every signal raises at once (the flight's supervision, its stopping: a second
    signal skips to stopping the simulators). `keeping()` goes back to keeping (the report is
    written whole; `signum` says a signal came). The previous handlers come back on exit."""

    def __init__(self, signals: tuple[int, ...] = INTERRUPTS) -> None:
        self.signals = signals
        self.kept: list[int] = []
        self._raise = False
        self._old: dict[int, object] = {}

    def __enter__(self) -> KeptSignals:
        for sig in self.signals:
            self._old[sig] = signal.signal(sig, self._on_signal)
        return self

    def __exit__(self, *exc) -> None:
        for sig, old in self._old.items():
            signal.signal(sig, old)

    def _on_signal(self, signum: int, _frame) -> None:
        self.kept.append(signum)
        if self._raise:
            raise Interrupted(signum)

    @property
    def signum(self) -> int | None:
        """The first signal that came (None: none yet)."""
        return self.kept[0] if self.kept else None

    def act(self) -> None:
        """Raise Interrupted for the first signal kept, if one came."""
        if self.kept:
            raise Interrupted(self.kept[0])

    def raising(self, act: bool = True) -> None:
        """From now on a signal raises at once; one kept before raises now (with `act`)."""
        self._raise = True
        if act:
            self.act()

    def keeping(self) -> None:
        """From now on a signal is kept again (`signum` tells later)."""
        self._raise = False


def interrupted(e: BaseException) -> tuple[int, str]:
    """(exit code, why) of a KeyboardInterrupt / runio.Interrupted: 128 + the signal number."""
    signum = getattr(e, "signum", signal.SIGINT)
    name = signal.Signals(signum).name
    return (
        128 + signum,
        "interrupted (Ctrl-C)" if signum == signal.SIGINT else f"interrupted ({name})",
    )


class CtrlC:
    """SIGINT (Ctrl-C) while `skyherd watch` runs: noted (`requested`), never raised where
    it lands.

    watch takes SIGINT for the whole command, from before its Zenoh session opens until its
    run folder is written, whatever the process inherited. A background job of a
    non-interactive shell (`cmd &` in a script) starts with SIGINT ignored; watch used to take
    it for its frame loop only, so a Ctrl-C during start-up (even just after metrics.csv
    appeared) was lost and watch waited on until --timeout (the suite saw no exit 120 s after
    SIGINT, --timeout 300). The flag is checked once the session is open and between frames:
    the KeyboardInterrupt that ends the run is raised outside every lock and Zenoh call, and a
    second Ctrl-C cannot cut the ending (session closed, summary.md) half-way. A plain
    attribute, no lock: a handler may run inside another one."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum, frame) -> None:
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


def say_ready() -> None:
    """Tell `skyherd fly` (runio.launch) that this child's own signal handlers are in place, so
    its SIGINT can come now: one byte on the pipe it named. Before that a SIGINT could land in
    the interpreter's start-up (a fatal error and a traceback) or inside a ctypes callback while
    numba loads a cached kernel (a KeyboardInterrupt printed as "Exception ignored" and lost:
    the flight flew on). The name is not passed on to this process's own children."""
    fd = os.environ.pop(READY_FD_ENV, None)
    if fd is None:
        return
    try:
        os.write(int(fd), b"1")
        os.close(int(fd))
    except (OSError, ValueError):
        pass  # not a pipe of fly's (a variable left in a shell): nothing to say
