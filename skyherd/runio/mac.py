"""The MAC of a JSON record on Zenoh (issue 27): what every JSON publication of a signed flight
carries, and what its readers check.

With the flight's key (the 32-byte MAVLink signing key, flight.mavlink.signing; `skyherd fly`
makes one per run) a record carries "mac": the hex BLAKE2b-256, keyed with the flight key, of
the record's JSON without "mac" (keys sorted, compact separators: its canonical body). A reader
given the key refuses (counts, never keeps) a record without it or whose MAC fails. The records
signed so: UGV states (groundsim.transport), the simulator's clock (world.scene), the camera's
info (perception.transport), the companion's decisions (mission.flight) and its safety net's
events (safety.events). Without a key a record is sent as it was, with no "mac".

One encoding per record on each side (issue 31): `sign_record` encodes the canonical body once,
MACs those bytes and sends them with `,"mac":"<64 hex>"` spliced in as the last member, so the
payload is the body's bytes plus the mac (`sign_body` signs a body its writer made itself: the
UGV states and the clock, fixed records written without json's encoder, tested equal to it).
`payload_ok` checks such a payload over the received bytes (the body is the payload with that
last member cut out: no re-encoding); a payload of any other shape (an older writer's spaced
JSON, another tool's key order, a second or misplaced "mac") is checked as before, by
re-encoding the parsed record (`record_ok`). Both checks MAC the same canonical bytes, so either
side can be old or new: the MAC is unchanged on the wire.

Why the byte check accepts nothing the re-encoding check refuses: it accepts only when the MAC
of the cut-out body is right, i.e. (without the key) the body is a canonical body some signer
MAC'd: a JSON object without a "mac" member. The payload is then that object with one "mac"
member appended, which parses to the signed record plus its mac: what `record_ok` accepts too.
"""

from __future__ import annotations

import hashlib
import hmac
import json

MAC_FIELD = "mac"

_HEX = 64  # the hex BLAKE2b-256
_LEAD = b',"' + MAC_FIELD.encode() + b'":"'  # the spliced member: _LEAD + hex + b'"' before "}"
_TAIL = len(_LEAD) + _HEX + 2  # the spliced member and the closing '"}'
_CANONICAL = json.JSONEncoder(sort_keys=True, separators=(",", ":"))  # made once, not per call


def _body(rec: dict) -> bytes:
    """The canonical body of a record: its JSON without "mac", keys sorted, compact (ASCII)."""
    if MAC_FIELD in rec:
        rec = {k: v for k, v in rec.items() if k != MAC_FIELD}
    return _CANONICAL.encode(rec).encode()


def _mac(key: bytes, body: bytes) -> str:
    return hashlib.blake2b(body, key=key, digest_size=32).hexdigest()


def record_mac(key: bytes, rec: dict) -> str:
    """The MAC of a JSON record (module docstring), "mac" itself left out."""
    return _mac(key, _body(rec))


def sign_record(rec: dict, key: bytes | None, sort_keys: bool = False) -> bytes:
    """The payload of `rec` (UTF-8 JSON). With a key: its canonical body with "mac" spliced in
    as the last member (sort_keys does not apply: the keys are sorted, "mac" last); without,
    the record as it is (keys in its order unless sort_keys)."""
    if key is None:
        return json.dumps(rec, sort_keys=sort_keys).encode()
    return sign_body(_body(rec), key)


def sign_body(body: bytes, key: bytes) -> bytes:
    """The signed payload of a record whose canonical body is `body` (a writer that makes its
    fixed records' bodies itself, e.g. groundsim.transport, signs them so)."""
    tag = _mac(key, body).encode()
    if body == b"{}":
        return b'{"' + MAC_FIELD.encode() + b'":"' + tag + b'"}'
    return body[:-1] + _LEAD + tag + b'"}'


def record_ok(rec: dict, key: bytes) -> bool:
    """Whether a received record carries the right MAC for `key` (re-encodes its body)."""
    mac = rec.get(MAC_FIELD)
    return isinstance(mac, str) and hmac.compare_digest(mac, record_mac(key, rec))


def payload_ok(payload: bytes, rec: dict, key: bytes) -> bool:
    """Whether a received payload carries the right MAC for `key`; `rec` is the payload parsed
    (json.loads(payload)). As `sign_record` writes it, the MAC is checked over the received
    bytes; in any other shape, or if that fails, by re-encoding `rec` (module docstring)."""
    n = len(payload) - _TAIL
    if n > 1 and payload[n : n + len(_LEAD)] == _LEAD and payload[-2:] == b'"}':
        tag = payload[n + len(_LEAD) : -2]
        if hmac.compare_digest(_mac(key, payload[:n] + b"}").encode(), tag):
            return True
    return record_ok(rec, key)
