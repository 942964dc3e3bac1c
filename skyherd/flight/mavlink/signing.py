"""MAVLink 2 message signing (https://mavlink.io/en/guide/message_signing.html).

A signed frame has incompat flag 0x01 and 13 more bytes: link id (1), timestamp (6, little
endian, units of 10 us since 2015-01-01 00:00 UTC), signature (6) = the first 48 bits of
SHA-256(secret key + frame header..CRC + link id + timestamp). Our own implementation
(pymavlink's is used by the tests to cross-check it both ways).

Acceptance once a key is set (`Signing.verify`):
- an unsigned frame (MAVLink 1, or no flag) only if its message is in ACCEPT_UNSIGNED, the
  list ArduPilot accepts unsigned on its radio links: RADIO_STATUS (a SiK radio cannot sign);
- the signature must match the key;
- per stream (link id, system, component) the timestamp must grow; a stream not seen before
  may be at most one minute (6,000,000 units) behind our local time, the larger of the wall
  clock and the newest timestamp seen or sent. The signature is checked before any timestamp
  is updated, so a forged frame cannot move a stream's timestamp.
Outgoing timestamps are max(wall clock, last + 1): strictly increasing across all links.
Signing times are wall time by the spec (peers compare them with their own clocks), unlike
every other time of the endpoint.

A key of 32 zero bytes means "signing off" (SETUP_SIGNING with it disables signing, as ArduPilot
does). The key files and how a flight is signed are flight.mavlink.keys' (re-exported here).
"""

from __future__ import annotations

import hashlib
import hmac
import time
from collections import Counter, OrderedDict

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.mavlink.keys import (  # noqa: F401  (their home before keys')
    KEY_LEN,
    PER_RUN_KEY_FILE,
    FlightSigning,
    SigningError,
    key_from_passphrase,
    key_option,
    load_key,
    save_key,
)
from skyherd.flight.mavlink.wire import CRC, X25

SIGNATURE_LEN = 13
IFLAG_SIGNED = 0x01
EPOCH_2015_S = 1420070400  # Unix time of 2015-01-01 00:00:00 UTC
UNITS_PER_S = 100_000  # timestamp unit: 10 us
REPLAY_WINDOW = 60 * UNITS_PER_S  # a new stream may be one minute behind our time
ACCEPT_UNSIGNED = frozenset({mavlink.MAVLINK_MSG_ID_RADIO_STATUS})
MAX_STREAMS = 256  # streams remembered; only correctly signed frames create one
_TS_MASK = (1 << 48) - 1  # a signature carries the timestamp's low 6 bytes


def now_units() -> int:
    """The signing clock: wall time in 10 us units since 2015-01-01 UTC."""
    return int((time.time() - EPOCH_2015_S) * UNITS_PER_S)


def is_signed(frame: bytes) -> bool:
    return len(frame) > 2 and frame[0] == 0xFD and bool(frame[2] & IFLAG_SIGNED)


class Signing:
    """The signing state of one system, shared by all its links (each has its own link id)."""

    def __init__(self, key: bytes | None = None, initial_timestamp: int = 0):
        self.key: bytes | None = None
        self.timestamp = 0  # newest timestamp sent or accepted [10 us since 2015]
        self._streams: OrderedDict[tuple[int, int, int], int] = OrderedDict()
        self.stats: Counter[str] = Counter()
        self.set_key(key, initial_timestamp)

    @property
    def enabled(self) -> bool:
        return self.key is not None

    def set_key(self, key: bytes | None, initial_timestamp: int = 0) -> None:
        """Use `key` from now on (None or 32 zero bytes: signing off). A new key starts the
        streams afresh; the same key again keeps them (else its recent frames could replay)."""
        if key is not None:
            key = bytes(key)
            if len(key) != KEY_LEN:
                raise SigningError(f"a signing key has {KEY_LEN} bytes, got {len(key)}")
            if not any(key):
                key = None
        if key != self.key:
            self._streams.clear()
        self.key = key
        self._key_hash = hashlib.sha256(key) if key is not None else None  # copied per frame
        self.timestamp = max(self.timestamp, int(initial_timestamp))

    def sign(self, frame: bytes, link_id: int) -> bytes:
        """The signed version of one unsigned MAVLink 2 frame (MAVLink 1 cannot be signed)."""
        if self.key is None or frame[0] != 0xFD or frame[2] & IFLAG_SIGNED:
            return frame
        msg_type = mavlink.mavlink_map.get(frame[7] | frame[8] << 8 | frame[9] << 16)
        if msg_type is None:
            return frame
        buf = bytearray(frame[:-2])
        buf[2] |= IFLAG_SIGNED  # the flag is inside the CRC: recompute it
        buf += CRC.pack(X25(bytes((msg_type.crc_extra,)), X25(bytes(buf[1:]))))
        return self.sign_frames([bytes(buf)], link_id)[0]

    def sign_frames(self, frames: list[bytes], link_id: int) -> list[bytes]:
        """Frames whose headers have IFLAG_SIGNED and whose CRCs cover it, each followed by
        its 13 bytes: link id, its timestamp, the first 6 bytes of SHA-256(key + frame + both).
        One clock reading for the batch, the timestamps consecutive from max(clock, last + 1);
        the key's hash state is computed once per key and copied, not re-hashed per frame."""
        ts = max(now_units(), self.timestamp + 1)
        self.timestamp = ts + len(frames) - 1
        link = bytes((link_id & 0xFF,))
        key_hash = self._key_hash
        out = []
        for frame in frames:
            tail = link + (ts & _TS_MASK).to_bytes(6, "little")
            h = key_hash.copy()
            h.update(frame + tail)
            out.append(frame + tail + h.digest()[:6])
            ts += 1
        return out

    def verify(self, frame: bytes, msg_id: int, src_system: int, src_component: int) -> str | None:
        """None if the frame is acceptable, else why it is rejected (counted in `stats`)."""
        if self.key is None:
            return None
        if not is_signed(frame):
            if msg_id in ACCEPT_UNSIGNED:
                self.stats["unsigned_accepted"] += 1
                return None
            return self._reject("unsigned")
        n = len(frame)
        if n < 10 + SIGNATURE_LEN + 2:
            return self._reject("bad signature")
        h = self._key_hash.copy()
        h.update(frame[:-6])
        if not hmac.compare_digest(h.digest()[:6], frame[-6:]):
            return self._reject("bad signature")
        ts = int.from_bytes(frame[n - 12 : n - 6], "little")
        stream = (frame[n - 13], src_system, src_component)  # link id, system, component
        streams = self._streams
        last = streams.get(stream)
        if last is None:
            if ts + REPLAY_WINDOW < max(self.timestamp, now_units()):
                return self._reject("timestamp more than a minute old")
            streams[stream] = ts
            if len(streams) > MAX_STREAMS:
                streams.popitem(last=False)
        elif ts <= last:
            return self._reject("replayed")
        else:
            streams[stream] = ts
            streams.move_to_end(stream)
        if ts > self.timestamp:
            self.timestamp = ts
        self.stats["signed_accepted"] += 1
        return None

    def _reject(self, why: str) -> str:
        self.stats[f"rejected_{why.split()[0]}"] += 1
        return why
