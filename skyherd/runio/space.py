"""Records that degrade instead of stopping the flight: a stream (CSV, JSON lines, tlog, MCAP)
that meets a full disk or a read-only folder stops appending, says so once on stderr, and counts
the records it dropped; the vehicle flies on and lands, and the run's summary says the records
were cut and why.

A full disk is seen before it is full: a stream stops when less than `RESERVE_BYTES` would be
left free, so that the files that say how the run ended (summary.md, companion.json,
sim_stats.json, a few KiB each) still fit. Free space is looked up once per `CHECK_BYTES` a
stream writes (one `statvfs`), so several streams may overshoot the reserve by that much each.
Everything written before the cut stays readable (each record is appended and flushed).
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

from skyherd.runio.process import say

RESERVE_BYTES = 256 * 1024  # free space kept for the run's end files [bytes]
CHECK_BYTES = 16 * 1024  # a stream looks up the free space once per this much written [bytes]


def free_bytes(path: Path | str) -> int | None:
    """Bytes free for an unprivileged writer on the file system holding `path` (None: unknown)."""
    try:
        st = os.statvfs(path)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def low_space(path: Path | str, reserve: int = RESERVE_BYTES) -> str | None:
    """Why a stream in folder `path` must stop before the disk is full, or None."""
    free = free_bytes(path)
    if free is not None and free < reserve:
        return (f"{os.strerror(errno.ENOSPC)}: {free // 1024} KiB free, "
                f"the last {reserve // 1024} KiB are kept for the run's summary")  # fmt: skip
    return None


def warn(text: str) -> None:
    """One line on stderr; never raises (stderr may itself be a file on the full disk)."""
    say(f"skyherd: warning: {text}")


def cut_records(writers) -> list[dict]:
    """The streams among `writers` that were cut: [{"file", "error", "dropped"}] (for the
    run's end files); None entries and streams that never failed are left out."""
    out = []
    for w in writers:
        a = getattr(w, "appender", w)
        err = getattr(a, "error", None)
        if err:
            out.append({"file": Path(a.path).name, "error": err,
                        "dropped": getattr(a, "dropped", None)})  # fmt: skip
    return out


class Appender:
    """An append-only file, written unbuffered per `write` (a str is written as UTF-8), that
    degrades: on a failed open or write, or when the free space falls below the reserve, it
    closes, sets `error` (why) and warns once, then counts each later `write` in `dropped`. A
    write that fails half-way is cut back off the file: it ends on a whole record."""

    def __init__(self, path: Path | str, reserve: int = RESERVE_BYTES):
        self.path = Path(path)
        self.error: str | None = None
        self.dropped = 0  # records not written since the cut
        self.reserve = reserve
        self._unchecked = 0  # bytes written since the last free-space look-up
        self._f = None
        try:
            self._f = open(self.path, "ab", buffering=0)  # noqa: SIM115 - closed in close()
            self._size = os.fstat(self._f.fileno()).st_size  # the whole records so far [bytes]
        except OSError as e:
            self._cut(_why(e))
            return
        why = low_space(self.path.parent, reserve)
        if why is not None:
            self._cut(why)

    @property
    def active(self) -> bool:
        return self._f is not None

    def write(self, data: str | bytes) -> bool:
        """Append and flush `data` (one or more whole records); False if it was dropped."""
        if self._f is None:
            self.dropped += 1
            return False
        self._unchecked += len(data)
        if self._unchecked >= CHECK_BYTES:
            self._unchecked = 0
            why = low_space(self.path.parent, self.reserve)
            if why is not None:
                self._cut(why)
                self.dropped += 1
                return False
        raw = data.encode("utf-8") if isinstance(data, str) else data
        view = memoryview(raw)
        try:
            while view:  # a disk that fills mid-write writes part, then fails
                view = view[self._f.write(view) :]
        except OSError as e:
            with contextlib.suppress(OSError):  # no torn record: cut back to the last whole one
                os.ftruncate(self._f.fileno(), self._size)
            self._cut(_why(e))
            self.dropped += 1
            return False
        self._size += len(raw)
        return True

    def _cut(self, why: str) -> None:
        f, self._f = self._f, None
        if f is not None:
            with contextlib.suppress(OSError):
                f.close()
        if self.error is None:
            self.error = why
            warn(f"{self.path}: records cut ({why}); the flight goes on, later records are dropped")

    def close(self) -> None:
        f, self._f = self._f, None
        if f is not None:
            try:
                f.close()
            except OSError as e:
                self.error = self.error or _why(e)


def _why(e: OSError) -> str:
    return e.strerror or str(e)
