"""`ZenohRecorder(session, vehicle, path)`: record a flight from the Zenoh keys of
CONVENTIONS.md, so that a flight flown by other processes (or on another host) is recorded.

Keys → channels (record.messages):

    skyherd/<vehicle>/camera/frame   → /<vehicle>/camera/image (JPEG as received; raw frames
                                       are JPEG-encoded) and /<vehicle>/pose (the frame header's
                                       pose), stamped with the header's simulation time
    skyherd/ugv/*/state              → /ugvs (one entity per UGV, replaced on each state)
    skyherd/<vehicle>/decision       → /<vehicle>/decision, /<vehicle>/phi, /<vehicle>/setpoint
    skyherd/<vehicle>/safety/event   → /<vehicle>/safety/event and /<vehicle>/log
    skyherd/sim/clock                → /sim/clock

A payload that does not parse (or, with the flight's key, is not authentic) is counted in
`corrupt[key kind]` and skipped; at close the counts go into the file as the MCAP metadata
record "skyherd zenoh" (authenticated, received, corrupt: JSON strings).
"""

from __future__ import annotations

import json
import math
import struct
from pathlib import Path
from typing import Any

from skyherd.record.flightlog import FlightLog
from skyherd.record.mcap_file import FlightRecorder
from skyherd.runio.constants import CLOCK_KEY
from skyherd.runio.mac import record_ok

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
    rec = json.loads(payload.decode())
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
        v = vehicle
        self._subs = [
            session.declare_subscriber(f"skyherd/{v}/camera/frame", self._wrap("frame", self._frame)),
            session.declare_subscriber("skyherd/ugv/*/state", self._wrap("ugv", self._ugv)),
            session.declare_subscriber(f"skyherd/{v}/decision", self._wrap("decision", self._decision)),
            session.declare_subscriber(f"skyherd/{v}/safety/event", self._wrap("event", self._event)),
            session.declare_subscriber(CLOCK_KEY, self._wrap("clock", self._clock)),
        ]  # fmt: skip

    def _wrap(self, kind: str, fn):
        def cb(sample) -> None:
            try:
                fn(sample.payload.to_bytes())
            except Exception:  # noqa: BLE001 - bad input on the wire is counted, never raised
                self.corrupt[kind] = self.corrupt.get(kind, 0) + 1
                return
            self.received[kind] = self.received.get(kind, 0) + 1

        return cb

    def _frame(self, payload: bytes) -> None:
        from skyherd.perception.transport import JPEG, decode_header, decode_pixels, pixel_data

        hdr = decode_header(payload, key=self.key)
        if hdr.encoding == JPEG:  # stored as it arrived, once its digest is checked
            self.log.frame(hdr.t_sim, jpeg=bytes(pixel_data(hdr, payload)), vehicle=self.vehicle)
        else:
            self.log.frame(hdr.t_sim, decode_pixels(hdr, payload).image, vehicle=self.vehicle)
        self.log.pose(hdr.t_sim, hdr.pos_ned, hdr.quat, vehicle=self.vehicle)

    def _json(self, payload: bytes) -> dict[str, Any]:
        rec = json.loads(payload.decode())
        if not isinstance(rec, dict):
            raise ValueError("not a JSON object")
        return rec

    def _authentic(self, rec: dict) -> dict:
        if self.key is not None and not record_ok(rec, self.key):
            raise ValueError("record MAC does not match the flight key")
        return rec

    def _ugv(self, payload: bytes) -> None:
        rec = self._authentic(self._json(payload))
        self.log.ugvs(_t(rec), [rec])

    def _decision(self, payload: bytes) -> None:
        rec = self._authentic(self._json(payload))
        self.log.decision(_t(rec), rec, vehicle=self.vehicle)

    def _event(self, payload: bytes) -> None:
        rec = self._authentic(self._json(payload))
        self.log.event(_t(rec), rec, vehicle=self.vehicle)

    def _clock(self, payload: bytes) -> None:
        if self.key is not None:
            self._authentic(self._json(payload))
        self.log.clock(clock_time(payload))

    def close(self) -> None:
        for s in self._subs:
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass
        file = getattr(self.log, "file", None)
        if file is not None:  # what came and what was refused, in the file itself
            file.metadata(ZENOH_METADATA, {"authenticated": json.dumps(self.key is not None),
                                           "received": json.dumps(self.received, sort_keys=True),
                                           "corrupt": json.dumps(self.corrupt, sort_keys=True)})  # fmt: skip
        self.log.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()
