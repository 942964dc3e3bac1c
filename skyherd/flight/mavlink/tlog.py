"""MAVLink telemetry logs (.tlog), readable by pymavlink and MAVExplorer.

Each record is an 8-byte big-endian timestamp in microseconds since the Unix epoch, then one
MAVLink frame (callers log parsed frames, never raw datagrams, so trailing bytes cannot corrupt
the log and a datagram holding two frames gives two records). With a `SimClock` the stamp is
(wall time at open) + simulation time, so a replay keeps the simulation's timing at any
speed-up; without one it is the wall clock (a client recording an outside vehicle). Records
are appended; `flush_interval_s` 0 flushes each one (a kill loses nothing already written), a
larger value batches flushes for busy endpoints.

Logging never takes the vehicle or the companion down: a failure to open, write or flush (a
full disk, a read-only directory) is reported once (`error`, a log warning, `on_error`), and
logging stops while everything else goes on. SETUP_SIGNING frames (they carry the secret key)
are never written.
"""

from __future__ import annotations

import errno
import logging
import struct
import threading
import time
from collections.abc import Callable
from pathlib import Path

from skyherd.flight.clock import SimClock
from skyherd.runio.space import CHECK_BYTES, low_space

log = logging.getLogger(__name__)
SETUP_SIGNING_ID = 256
_STAMP = struct.Struct(">Q")  # record header: µs since the Unix epoch, big-endian
_SIGNING_ID_V2 = SETUP_SIGNING_ID.to_bytes(3, "little")


class TlogWriter:
    def __init__(
        self,
        path: Path,
        clock: SimClock | None = None,
        flush_interval_s: float = 0.0,
        on_error: Callable[[str], None] | None = None,
    ):
        self.path = Path(path)
        self.error: str | None = None  # why logging stopped (None while it works)
        self.records = 0
        self._on_error = on_error
        self._clock = clock
        self._epoch_us = int(time.time() * 1e6)
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._lock = threading.RLock()  # re-entrant: on_error may send (and log) a STATUSTEXT
        self._f = None
        self._unchecked = 0  # bytes written since the last free-space look-up
        try:
            self._f = open(self.path, "ab")
        except OSError as e:
            self._fail("open", e)

    @property
    def active(self) -> bool:
        return self._f is not None

    def stamp_us(self) -> int:
        """The stamp a record written now gets [µs since the Unix epoch]."""
        return self._stamp_us()

    def _stamp_us(self) -> int:
        if self._clock is None:
            return int(time.time() * 1e6)
        return self._epoch_us + self._clock.time_us

    def _fail(self, what: str, e: OSError) -> None:
        """Stop logging and say so once."""
        f, self._f = self._f, None
        if f is not None:
            try:
                f.close()  # flushes what is buffered: fails again on a full disk
            except OSError:
                pass
        if self.error is not None:
            return
        self.error = (
            f"tlog {self.path.name}: cannot {what} ({e.strerror or e}); telemetry logging stopped"
        )
        log.warning("%s (%s)", self.error, self.path)
        if self._on_error is not None:
            self._on_error(self.error)

    def write(self, frame: bytes) -> None:
        self.write_many((frame,))

    def write_many(self, frames, stamp_us: int | None = None) -> None:
        """Append frames (one datagram's, one send's) as one write, each with the same stamp
        (`stamp_us`, default now); with `flush_interval_s` 0 they are flushed together before
        this returns."""
        if self._f is not None:
            self.write_stamped([(self._stamp_us() if stamp_us is None else stamp_us, frames)])

    def write_stamped(self, groups: list[tuple[int, list[bytes]]]) -> None:
        """`write_many` of several (stamp [µs], frames) groups in order, as one write (and with
        `flush_interval_s` 0 one flush): a lockstep tick's held records cost one system call."""
        if self._f is None:
            return
        # SETUP_SIGNING (id 256) exists only in MAVLink 2: bytes 7..9 of a v2 frame hold its id
        kept = []
        for stamp_us, frames in groups:
            stamp = _STAMP.pack(stamp_us)
            kept += [stamp + f for f in frames if f[7:10] != _SIGNING_ID_V2 or f[0] != 0xFD]
        if not kept:
            return
        data = b"".join(kept)
        with self._lock:
            if self._f is None:
                return
            self._unchecked += len(data)
            if self._unchecked >= CHECK_BYTES:  # stop before the disk is full (runio.space)
                self._unchecked = 0
                why = low_space(self.path.parent)
                if why is not None:
                    self._fail("write", OSError(errno.ENOSPC, why))
                    return
            try:
                self._f.write(data)
                if self._flush_interval_s <= 0:
                    self._f.flush()
                self.records += len(kept)
            except OSError as e:
                self._fail("write", e)

    def maybe_flush(self) -> None:
        """Flush when `flush_interval_s` of wall time has passed since the last flush."""
        now = time.monotonic()
        if self._f is None or now - self._last_flush <= self._flush_interval_s:
            return
        with self._lock:
            if self._f is not None:
                try:
                    self._f.flush()
                except OSError as e:
                    self._fail("write", e)
        self._last_flush = now

    def close(self) -> None:
        """Flush and close (a failure is reported like any other); later writes are ignored."""
        with self._lock:
            f, self._f = self._f, None
            if f is None:
                return
            try:
                f.close()
            except OSError as e:
                self._f = f
                self._fail("write", e)
