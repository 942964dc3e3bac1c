"""UGV states over Zenoh: `skyherd/ugv/<id>/state` (CONVENTIONS.md), one JSON object per UGV.

Payload (UTF-8 JSON): {"id": int, "seq": int, "t_sim": s, "pos_ned": [n, e, d] m,
"heading_rad": from north clockwise, "speed_mps": m/s, "camouflaged": bool}. JSON keeps the
records readable by any Zenoh tool (`z_sub -k 'skyherd/ugv/**'`); at a few UGVs × 10–50 Hz
the size does not matter.

With the flight's key (the 32-byte MAVLink signing key; `skyherd fly` signs by default) every
record carries "mac" (runio.mac: keyed BLAKE2b-256 of the record without it); a subscriber given
the key refuses (counts in `refused`, never keeps) a record without it or whose MAC fails.
Signed, a record is its canonical JSON (keys sorted, compact) with "mac" as the last member,
checked over the received bytes (runio.mac.payload_ok).
Without a key the records are as before, with no "mac".

Sessions come from `perception.transport.open_session` (loopback peer by default).
"""

from __future__ import annotations

import json
import math
import threading

import numpy as np

from skyherd.groundsim.ugv import UGVStates
from skyherd.runio.mac import payload_ok, sign_body, sign_record

# A signed state's canonical body (runio.mac: keys sorted, compact separators) written
# directly: json's encoder took twice as long (~4 µs a record, 3 records every camera instant).
# Numbers as json writes finite ones (repr); the tests hold it to runio.mac's encoding.
_SIGNED_BODY = (
    '{"camouflaged":%s,"heading_rad":%r,"id":%d,"pos_ned":[%r,%r,0.0],"seq":%d,'
    '"speed_mps":%r,"t_sim":%r}'
)


def state_key(ugv_id: int | str) -> str:
    return f"skyherd/ugv/{ugv_id}/state"


def state_payload(key: bytes | None, ugv_id: int, seq: int, t_sim: float, north: float,
                  east: float, heading: float, speed: float, camouflaged: bool) -> bytes:  # fmt: skip
    """One UGV's state record (module docstring) as sent: signed with `key` unless None."""
    t_sim, north, east = float(t_sim), float(north), float(east)
    heading, speed, camouflaged = float(heading), float(speed), bool(camouflaged)
    if key is not None and all(map(math.isfinite, (t_sim, north, east, heading, speed))):
        body = _SIGNED_BODY % ("true" if camouflaged else "false", heading, ugv_id, north, east,
                               seq, speed, t_sim)  # fmt: skip
        return sign_body(body.encode(), key)
    rec = {"id": ugv_id, "seq": seq, "t_sim": t_sim, "pos_ned": [north, east, 0.0],
           "heading_rad": heading, "speed_mps": speed, "camouflaged": camouflaged}  # fmt: skip
    return sign_record(rec, key)  # json writes NaN and Infinity


class UGVStatePublisher:
    """Publishes every UGV's state on its own key."""

    def __init__(self, session, n_ugv: int, key: bytes | None = None):
        self._pubs = [session.declare_publisher(state_key(i)) for i in range(n_ugv)]
        self.seq = 0
        self.key = key  # the flight key: records carry "mac"

    def publish(self, t_sim: float, states: UGVStates) -> None:
        # Python numbers once per call (one numpy scalar per field and UGV costs more)
        pos, heading = np.asarray(states.pos_ne).tolist(), np.asarray(states.heading).tolist()
        speed = np.asarray(states.speed).tolist()
        camouflaged = np.asarray(states.camouflaged).tolist()
        for i, pub in enumerate(self._pubs):
            pub.put(state_payload(self.key, i, self.seq, t_sim, pos[i][0], pos[i][1], heading[i],
                                  speed[i], camouflaged[i]))  # fmt: skip
        self.seq += 1

    def close(self) -> None:
        for p in self._pubs:
            try:
                p.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass


class UGVStateSubscriber:
    """Keeps the newest state of each UGV (`skyherd/ugv/*/state`); bad records are counted."""

    def __init__(self, session, key: bytes | None = None):
        self._lock = threading.Lock()
        self.latest: dict[int, dict] = {}
        self.received = 0
        self.corrupt = 0
        self.refused = 0  # with a key: records without a valid "mac"
        self.key = key
        self._sub = session.declare_subscriber("skyherd/ugv/*/state", self._on_sample)

    def _on_sample(self, sample) -> None:
        try:
            payload = sample.payload.to_bytes()
            rec = json.loads(payload.decode())
            i = int(rec["id"])
            pos = [float(x) for x in rec["pos_ned"]]
            ok = len(pos) == 3 and all(math.isfinite(x) for x in pos)
            ok = ok and math.isfinite(float(rec["t_sim"])) and math.isfinite(rec["heading_rad"])
            if not ok:
                raise ValueError("non-finite state")
        except (ValueError, KeyError, TypeError, UnicodeDecodeError):
            with self._lock:
                self.corrupt += 1
            return
        if self.key is not None and not payload_ok(payload, rec, self.key):
            with self._lock:
                self.refused += 1
            return
        with self._lock:
            old = self.latest.get(i)
            if old is None or rec["t_sim"] >= old["t_sim"]:
                self.latest[i] = rec
            self.received += 1

    def oldest_stamp(self, n_ugv: int) -> float:
        """The oldest newest-report time [s] among UGVs 0..n−1 (−inf while one never reported)."""
        with self._lock:
            return min(
                (self.latest[i]["t_sim"] if i in self.latest else -math.inf) for i in range(n_ugv)
            )

    def states(self, n_ugv: int) -> UGVStates | None:
        """The newest states of UGVs 0..n−1 as UGVStates, or None until all have reported."""
        with self._lock:
            if any(i not in self.latest for i in range(n_ugv)):
                return None
            recs = [self.latest[i] for i in range(n_ugv)]
        return UGVStates(
            np.array([r["pos_ned"][:2] for r in recs]),
            np.array([r["heading_rad"] for r in recs]),
            np.array([r["speed_mps"] for r in recs]),
            np.array([bool(r["camouflaged"]) for r in recs]),
        )

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception:  # noqa: BLE001 - already closed with its session
            pass
