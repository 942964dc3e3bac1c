"""`FlightRecorder`: a flight as an MCAP file (Foxglove, PlotJuggler open it as is).

Append-safe: the `mcap` writer gathers messages into a chunk; the chunk is closed and the file
flushed when it holds `chunk_bytes` or the newest message time has moved `chunk_s` of
simulation time since it opened (default 256 KiB / 1 s), so a kill loses at most the open chunk. A file cut anywhere reads back up to its last
complete chunk with `record.read.read_messages` (it walks the records without needing the
summary at the end). `close()` writes the summary and footer: a complete, indexed file.
A full disk (less than runio.space's reserve left after a chunk) or a failed write cuts the
recording: one warning, `error` says why, later messages raise (the FlightLog counts them), and
the file ends on its last complete chunk.
"""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Any

from mcap.writer import CompressionType, Writer

from skyherd.record import messages as m
from skyherd.record.flightlog import FlightLog
from skyherd.runio.space import RESERVE_BYTES, low_space, warn

PROFILE = ""  # no ROS profile: Foxglove protobuf and JSON channels


class McapFile:
    """A Sink writing an MCAP file (see the module docstring)."""

    def __init__(self, path: Path | str, chunk_bytes: int = 256 * 1024, chunk_s: float = 1.0,
                 compression: str = "zstd", metadata: dict[str, str] | None = None):  # fmt: skip
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._f = open(self.path, "wb")
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "none": CompressionType.NONE}[compression]  # fmt: skip
        # the writer's own size trigger is a backstop; chunks close here (_maybe_flush)
        self._w = Writer(self._f, chunk_size=4 * chunk_bytes, compression=comp)
        self._w.start(profile=PROFILE, library="skyherd record")
        if metadata:
            self._w.add_metadata("skyherd", {str(k): str(v) for k, v in metadata.items()})
        self._f.flush()
        self.chunk_bytes, self.chunk_ns = chunk_bytes, m.ns(chunk_s)
        self._schemas: dict[str, int] = {}
        self._open_bytes = 0
        self._open_since: int | None = None  # the newest log time when the chunk opened [ns]
        self._newest = -(2**63)  # the newest log time written [ns]
        self.chunks = 0
        self.messages = 0  # written so far
        self.flushed_messages = 0  # of those, in closed chunks (what a kill leaves readable)
        self._closed = False
        self.error: str | None = None  # why the recording was cut (None while it works)

    def channel(self, spec: m.ChannelSpec) -> int:
        s = spec.schema
        sid = self._schemas.get(s.name)
        if sid is None:
            sid = self._schemas[s.name] = self._w.register_schema(s.name, s.encoding, s.data)
        return self._w.register_channel(spec.topic, spec.message_encoding, sid)

    def write(self, handle: Any, t_ns: int, data: bytes) -> None:
        if self.error is not None:  # cut (a full disk): the recorder counts what it drops
            raise OSError(errno.ENOSPC, self.error)
        self._w.add_message(handle, log_time=t_ns, data=data, publish_time=t_ns)
        self._open_bytes += len(data)
        self.messages += 1
        # the span counts the newest time: streams on clocks a little apart (the UGVs' team
        # time trails the simulation's) must not close a chunk at every message
        self._newest = max(self._newest, t_ns)
        if self._open_since is None:
            self._open_since = self._newest
        if self._open_bytes >= self.chunk_bytes or self._newest - self._open_since >= self.chunk_ns:
            self.flush()

    def metadata(self, name: str, values: dict[str, str]) -> None:
        """A metadata record (`name`, string → string) at this point of the file."""
        if self.error is None and not self._closed:
            self._w.add_metadata(name, {str(k): str(v) for k, v in values.items()})

    def flush(self) -> None:
        """Close the open chunk and push it to the file (readable from here on)."""
        if self._open_bytes and self.error is None:
            # stop before the disk is full (runio.space): the chunk and the reserve must fit
            why = low_space(self.path.parent, RESERVE_BYTES + self._open_bytes)
            if why is not None:
                self.error = why
                warn(f"{self.path}: recording cut ({why}); the flight goes on")
                return
            try:
                self._w.flush()
            except OSError as e:  # a read-only folder, a disk filled by someone else
                self.error = e.strerror or str(e)
                warn(f"{self.path}: recording cut ({self.error}); the flight goes on")
                return
            self.chunks += 1
            self.flushed_messages = self.messages
        self._open_bytes, self._open_since = 0, None

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            self.flush()
            if self.error is None:  # cut: readable up to its last chunk, no summary
                self._w.finish()
        except OSError as e:
            self.error = self.error or (e.strerror or str(e))
        finally:
            try:
                self._f.close()
            except OSError:
                pass


class FlightRecorder(FlightLog):
    """`FlightRecorder(path)`: a FlightLog writing `path` (flight.mcap in a run folder).

    Extra sinks (e.g. a `record.live.LiveServer`'s) can be passed as `also=[...]`, so that one
    set of calls feeds the file and the live view."""

    def __init__(self, path: Path | str, *, also=(), metadata: dict[str, str] | None = None,
                 **mcap_options):  # fmt: skip
        self.file = McapFile(path, metadata=metadata, **mcap_options)
        extra = [getattr(a, "server_sink", a) for a in also]
        super().__init__(self.file, *extra)
        self.path = self.file.path
