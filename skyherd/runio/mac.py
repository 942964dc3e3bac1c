"""The MAC of a JSON record on Zenoh (issue 27): what every JSON publication of a signed flight
carries, and what its readers check.

With the flight's key (the 32-byte MAVLink signing key, flight.mavlink.signing; `skyherd fly`
makes one per run) a record carries "mac": the hex BLAKE2b-256, keyed with the flight key, of
the record's JSON without "mac" (keys sorted, compact separators). A reader given the key
refuses (counts, never keeps) a record without it or whose MAC fails. The records signed so:
UGV states (groundsim.transport), the simulator's clock (world.sim), the camera's info
(perception.transport), the companion's decisions (mission.flight) and its safety net's events
(safety.events). Without a key a record is sent as it was, with no "mac".
"""

from __future__ import annotations

import hashlib
import hmac
import json

MAC_FIELD = "mac"


def record_mac(key: bytes, rec: dict) -> str:
    """The MAC of a JSON record (module docstring), "mac" itself left out."""
    body = json.dumps({k: v for k, v in rec.items() if k != MAC_FIELD}, sort_keys=True,
                      separators=(",", ":"))  # fmt: skip
    return hashlib.blake2b(body.encode(), key=key, digest_size=32).hexdigest()


def sign_record(rec: dict, key: bytes | None, sort_keys: bool = False) -> bytes:
    """The payload of `rec` (UTF-8 JSON): with a key, the record with its "mac"; without, as
    it is."""
    if key is not None:
        rec = {**rec, MAC_FIELD: record_mac(key, rec)}
    return json.dumps(rec, sort_keys=sort_keys).encode()


def record_ok(rec: dict, key: bytes) -> bool:
    """Whether a received record carries the right MAC for `key`."""
    mac = rec.get(MAC_FIELD)
    return isinstance(mac, str) and hmac.compare_digest(mac, record_mac(key, rec))
