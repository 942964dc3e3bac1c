"""`ZenohRecorder(session, vehicle, path)`: record a flight from the Zenoh keys of
CONVENTIONS.md, so that a flight flown by other processes (or on another host) is recorded.

Keys → channels (record.messages):

    skyherd/<vehicle>/camera/frame   → /<vehicle>/camera/image (JPEG as received; raw frames
                                       are JPEG-encoded) and /<vehicle>/pose (the frame header's
                                       pose), stamped with the header's simulation time
    skyherd/ugv/*/state              → /ugvs (one entity per UGV, replaced on each state; the
                                       states of one simulation time in one message)
    skyherd/<vehicle>/decision       → /<vehicle>/decision, /<vehicle>/phi, /<vehicle>/setpoint
    skyherd/<vehicle>/safety/event   → /<vehicle>/safety/event and /<vehicle>/log
    skyherd/sim/clock                → /sim/clock

A payload that does not parse (or, with the flight's key, is not authentic: runio.mac, checked
over the received bytes) is counted in `corrupt[key kind]` and skipped; at close the counts go
into the file as the MCAP metadata record "skyherd zenoh" (authenticated, received, corrupt:
JSON strings).

Each key's callback only queues the sample's bytes (copied out at once: a camera frame's
shared-memory buffer goes back to the simulator's pool), and the recorder's own thread records
the queue every BATCH_S of wall time, in the order the samples came (a decision after the frame
it answered). In batches the recording costs a third less CPU than in each key's callback (in
a 100 s flight of 6,000 samples, 0.52 -> 0.35 s: a GIL hand-over per sample, and the caches
cold each time). A sample that comes while QUEUE samples or QUEUE_BYTES are waiting is dropped
and counted (`dropped`, in the metadata record when any was): the recorder never holds Zenoh's
threads back (a frame's buffer with them), nor grows without bound (camera frames are most of
the bytes: 230 kB raw at 320x240, 2.8 MB at 1280x720).
"""

from __future__ import annotations

import collections
import json
import math
import struct
import threading
from pathlib import Path
from typing import Any

from skyherd.record import messages as m
from skyherd.record.flightlog import FlightLog
from skyherd.record.mcap_file import FlightRecorder
from skyherd.runio.constants import CLOCK_KEY
from skyherd.runio.mac import payload_ok

ZENOH_METADATA = "skyherd zenoh"  # the MCAP metadata record of the counts, written at close


def clock_time(payload: bytes) -> float:
    """Simulation time [s] from a clock sample: JSON {"t_sim": s} (or "t", or "time_us" µs),
    or a bare little-endian float64 [s] / uint64 [µs] (8 bytes: a float64 if it is finite and
    below a year, else µs)."""
    if len(payload) == 8:
        (f,) = struct.unpack("<d", payload)
        if math.isfinite(f) and 0 <= f < 3.2e7:
            return f
        return struct.unpack("<Q", payload)[0] / 1e6
    return record_time(json.loads(payload.decode()))


def record_time(rec: Any) -> float:
    """Simulation time [s] from a parsed JSON clock sample (see `clock_time`)."""
    if isinstance(rec, int | float):
        return float(rec)
    if "time_us" in rec:
        return float(rec["time_us"]) / 1e6
    return float(rec["t_sim"] if "t_sim" in rec else rec["t"])


def _t(rec: dict[str, Any]) -> float:
    t = float(rec.get("t_sim", rec.get("t", 0.0)))
    if not math.isfinite(t):
        raise ValueError("non-finite time")
    return t


class ZenohRecorder:
    """Subscribes on `session` (an open zenoh session) and records into `path` until closed."""

    def __init__(self, session, vehicle: str, path: Path | str | None, *, also=(),
                 key: bytes | None = None, **mcap_options):  # fmt: skip
        """path None: no file, only the `also` sinks (e.g. a LiveServer: live view only).
        key: the flight key: camera frames, UGV states, the clock, the companion's decisions
        and its net's events that fail their MAC (perception.transport, runio.mac) are not
        recorded (counted in `corrupt`)."""
        self.vehicle = vehicle
        self.key = key
        if path is None:
            self.log = FlightLog(*(getattr(a, "server_sink", a) for a in also))
            self.path = None
        else:
            self.log = FlightRecorder(path, also=also, metadata={"vehicle": vehicle},
                                      **mcap_options)  # fmt: skip
            self.path = self.log.path
        self.log.advertise(vehicle)  # a live view shows every channel before the first message
        self.received: dict[str, int] = {}
        self.corrupt: dict[str, int] = {}
        # UGV states of one simulation time, drawn as one scene (`_ugv`)
        self._ugv_lock = threading.Lock()
        self._ugv_t: float | None = None
        self._ugv_batch: dict[str, Any] = {}  # id → its entity at _ugv_t (messages.ugv_entity)
        self._ugv_ids: set[str] = set()  # every UGV heard from
        self.dropped = 0  # samples that came while the queue was full (QUEUE, QUEUE_BYTES)
        self._queue: collections.deque[tuple[Any, bytes]] = collections.deque()
        self._queued_bytes = 0
        self._queue_lock = threading.Lock()  # Zenoh's threads append, the recorder's takes
        self._closing = threading.Event()
        v = vehicle
        self._subs = [
            session.declare_subscriber(f"skyherd/{v}/camera/frame", self._queued("frame", self._frame)),
            session.declare_subscriber("skyherd/ugv/*/state", self._queued("ugv", self._ugv)),
            session.declare_subscriber(f"skyherd/{v}/decision", self._queued("decision", self._decision)),
            session.declare_subscriber(f"skyherd/{v}/safety/event", self._queued("event", self._event)),
            session.declare_subscriber(CLOCK_KEY, self._queued("clock", self._clock)),
        ]  # fmt: skip
        # started once subscribed (what came meanwhile waits in the queue): no thread is left
        # running when a subscription fails
        self._thread = threading.Thread(target=self._run, name="skyherd-recorder", daemon=True)
        self._thread.start()

    # waiting for the recorder's thread, at most: half a minute of `make run`'s samples at
    # --speedup 0 (6,000 in ~3 s of wall time), 570 raw 320x240 frames
    QUEUE = 65536  # samples
    QUEUE_BYTES = 128 << 20  # payload bytes
    BATCH_S = 0.01  # [wall s] between the recorder thread's batches

    def _queued(self, kind: str, fn):
        """Zenoh's callback for a key: the sample's bytes queued for the recorder's thread."""
        how = (kind, fn)

        def cb(sample) -> None:
            payload = sample.payload.to_bytes()
            with self._queue_lock:
                if (len(self._queue) >= self.QUEUE
                        or self._queued_bytes + len(payload) > self.QUEUE_BYTES):  # fmt: skip
                    self.dropped += 1
                    return
                self._queue.append((how, payload))
                self._queued_bytes += len(payload)

        return cb

    def _run(self) -> None:
        """The recorder's thread: what came meanwhile, every BATCH_S, until close()."""
        while not self._closing.wait(self.BATCH_S):
            self._drain()

    def _drain(self) -> None:
        with self._queue_lock:  # the whole queue taken at once: the callbacks never wait long
            batch, self._queue = self._queue, collections.deque()
            self._queued_bytes = 0
        for (kind, fn), payload in batch:
            try:
                fn(payload)
            except Exception:  # noqa: BLE001 - bad input on the wire is counted, never raised
                self.corrupt[kind] = self.corrupt.get(kind, 0) + 1
                continue
            self.received[kind] = self.received.get(kind, 0) + 1

    def _frame(self, payload: bytes) -> None:
        from skyherd.perception.transport import JPEG, decode_header, decode_pixels, pixel_data

        hdr = decode_header(payload, key=self.key)
        if hdr.encoding == JPEG:  # stored as it arrived, once its digest is checked
            self.log.frame(hdr.t_sim, jpeg=bytes(pixel_data(hdr, payload)), vehicle=self.vehicle)
        else:
            self.log.frame(hdr.t_sim, decode_pixels(hdr, payload).image, vehicle=self.vehicle)
        self.log.pose(hdr.t_sim, hdr.pos_ned, hdr.quat, vehicle=self.vehicle)

    def _record(self, payload: bytes) -> dict[str, Any]:
        """The JSON object of a payload; with the flight key only an authentic one."""
        rec = json.loads(payload.decode())
        if not isinstance(rec, dict):
            raise ValueError("not a JSON object")
        if self.key is not None and not payload_ok(payload, rec, self.key):
            raise ValueError("record MAC does not match the flight key")
        return rec

    def _ugv(self, payload: bytes) -> None:
        """A UGV state joins the others of its simulation time; they are drawn as one scene
        (one /ugvs message, an entity per UGV: what Foxglove shows from one message per state)
        once every UGV heard from so far is in, or when a state of another time (or a second
        one of the same UGV) comes, or at close. Nothing is dropped or merged away."""
        rec = self._record(payload)
        t = _t(rec)
        ugv = str(rec.get("id"))
        with self._ugv_lock:
            if self._ugv_batch and (t != self._ugv_t or ugv in self._ugv_batch):
                self._draw_ugvs()
            # drawn now: a state that does not draw (a bad heading) is counted as it arrives
            entity = m.ugv_entity(m.stamp(t), rec, len(self._ugv_batch))
            if entity is None:  # no finite position: nothing to show
                return
            self._ugv_t = t
            self._ugv_batch[ugv] = entity
            self._ugv_ids.add(ugv)
            if len(self._ugv_batch) == len(self._ugv_ids):
                self._draw_ugvs()

    def _draw_ugvs(self) -> None:
        """The pending states as one scene (under _ugv_lock)."""
        batch, self._ugv_batch = self._ugv_batch, {}
        if batch and self._ugv_t is not None:
            self.log.ugv_entities(self._ugv_t, list(batch.values()))

    def _decision(self, payload: bytes) -> None:
        rec = self._record(payload)
        self.log.decision(_t(rec), rec, vehicle=self.vehicle)

    def _event(self, payload: bytes) -> None:
        rec = self._record(payload)
        self.log.event(_t(rec), rec, vehicle=self.vehicle)

    def _clock(self, payload: bytes) -> None:
        if self.key is None:
            t = clock_time(payload)
        else:  # signed: a JSON object, parsed once
            t = record_time(self._record(payload))
        self.log.clock(t)

    CLOSE_WAIT_S = 5.0  # [wall s] close() waits this long for the thread's batch in hand

    def close(self) -> None:
        """Stop the subscribers, record what is still queued, then close the file (its summary)."""
        for sub in self._subs:
            try:
                sub.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass
        self._closing.set()
        self._thread.join(self.CLOSE_WAIT_S)
        if not self._thread.is_alive():  # (a thread stuck in a sink: its queue is lost)
            self._drain()
        with self._ugv_lock:
            try:
                self._draw_ugvs()  # the last time's states, if they were not all in
            except Exception:  # noqa: BLE001 - a recorder never stops a flight
                pass
        file = getattr(self.log, "file", None)
        if file is not None:  # what came and what was refused, in the file itself
            counts = {"authenticated": json.dumps(self.key is not None),
                      "received": json.dumps(self.received, sort_keys=True),
                      "corrupt": json.dumps(self.corrupt, sort_keys=True)}  # fmt: skip
            if self.dropped:
                counts["dropped"] = json.dumps(self.dropped)
            file.metadata(ZENOH_METADATA, counts)
        self.log.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
