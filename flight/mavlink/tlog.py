"""MAVLink telemetry logs (.tlog), readable by pymavlink and MAVExplorer.

Each record is an 8-byte big-endian timestamp in microseconds since the Unix epoch, then the
raw frame. With a `SimClock` the stamp is (wall time at open) + simulation time, so a replay
keeps the simulation's timing at any speed-up; without one it is the wall clock (a client
recording an outside vehicle). Records are appended; `flush_interval_s` 0 flushes each one
(a kill loses nothing already written), a larger value batches flushes for busy endpoints.
"""

from __future__ import annotations

import struct
import threading
import time
from pathlib import Path

from flight.clock import SimClock


class TlogWriter:
    def __init__(self, path: Path, clock: SimClock | None = None, flush_interval_s: float = 0.0):
        self._f = open(path, "ab")
        self._clock = clock
        self._epoch_us = int(time.time() * 1e6)
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._lock = threading.Lock()

    def _stamp_us(self) -> int:
        if self._clock is None:
            return int(time.time() * 1e6)
        return self._epoch_us + self._clock.time_us

    def write(self, frame: bytes) -> None:
        with self._lock:
            self._f.write(struct.pack(">Q", self._stamp_us()) + frame)
            if self._flush_interval_s <= 0:
                self._f.flush()

    def maybe_flush(self) -> None:
        """Flush when `flush_interval_s` of wall time has passed since the last flush."""
        now = time.monotonic()
        if now - self._last_flush > self._flush_interval_s:
            with self._lock:
                self._f.flush()
            self._last_flush = now

    def close(self) -> None:
        with self._lock:
            self._f.close()
