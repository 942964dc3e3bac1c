"""Camera frames over Zenoh: publisher, subscriber, wire format, link statistics.

Keys (CONVENTIONS.md): `skyherd/<vehicle>/camera/frame` (one frame per sample) and
`skyherd/<vehicle>/camera/info` (camera intrinsics and mounting, JSON, sent with the first
frame and every `info_every` frames; with the flight's key it carries "mac", runio.mac, and a
subscriber with the key keeps only authentic info, counting the rest in `info_refused`).

Frame wire format (little-endian), then the pixel data:

    magic "SKYF" | version u16 (5 plain, 6 signed) | encoding u8 (0 raw RGB, 1 JPEG) |
    reserved u8 | stream u32 (random per publisher: a restart resets the subscriber's
    bookkeeping) | seq u64 | t_sim f64 [s] (simulation clock) | t_pub f64 [s] (publisher's wall
    clock) | pos_ned 3×f64 [m] | quat 4×f64 (w, x, y, z body→NED) | width u16 | height u16 |
    data_len u32 | nonce 16 bytes | digest 16 bytes | header_crc u32 (CRC-32 of the header
    before it)

Integrity is over the header; the pixels are authenticated only when there is something to
authenticate them against. A plain frame (version 5) carries no pixel digest (nonce and digest
are zero): its header CRC covers the header (sequence number, stream, pose, size and length
included), and the pixels are as intact as the link that carried them (TCP's checksum, or the
publisher's shared memory mapped by the subscriber). Nothing touches them between the
renderer and the put but the copy into shared memory. (Version 3 also summed the pixels: a
second pass per side, 0.03–0.11 ms per 640×480 frame, for damage that TCP and shared memory
do not do; issue 31 item 2.) A signed frame (version 6; publisher and subscriber given the
flight's key, `key`: the 32 bytes of the MAVLink signing key, flight.mavlink.signing) carries
the AES-GMAC of the pixels (AES-256-GCM's tag with the pixels as associated data and nothing
encrypted, OpenSSL's) under the flight's pixel key (BLAKE2b-256 keyed with the flight key,
derived once per key) with the first 12 bytes of the frame's random 16-byte `nonce` as GCM's
IV (random 96-bit IVs: one repeated among 2^32 frames of a flight has a chance below 2^-32,
NIST SP 800-38D's bound; a flight at 30 frames/s sends 2^32 frames in 4.5 years), and a
trailer after the pixels: BLAKE2b-256 keyed with the flight key over the header as sent (32
bytes, the digest included). Altering the header fails the MAC; altering a pixel fails the
digest, which no one without the flight key can compute for other pixels: the one pass over
the pixels that authenticity costs (bench/bench_frames.py, docs/perception.md). Version 4 was
the same with Poly1305 for the digest (about twice GMAC's CPU here, issue 31 item 2): like
version 3, it is no longer read (CorruptFrame, "no longer read").

A subscriber with a key refuses (counts as `refused`, never hands on) plain frames and frames
whose MAC or pixel digest fails, on arrival, before their sequence number touches the books: a
forged "next frame", or a real one with pixels altered, cannot push the real one out (a
signed frame decoded by `decode_pixels` gives RefusedFrame). A run of refused frames is a
camera that went silent: the consumer's camera-loss path. Readers without a key (the recorder
without one, a viewer) read both versions and check the header CRC (a signed frame's digest
needs the key).

Sessions: by default a Zenoh peer that listens on tcp/127.0.0.1 only (the publisher, runio.ports.zenoh_port)
or connects to it (the subscriber), multicast scouting off: nothing to start by hand, nothing
leaves the machine. `ZenohParams.config_file` hands the whole configuration to a Zenoh JSON5
file instead (e.g. client mode towards a router on another machine; see docs/perception.md).

The subscriber keeps only the newest frame. It counts frames received, lost (gaps in seq),
out of order (older than the newest, discarded; a lost frame that turns up late moves from
lost to out-of-order), late (wall-clock age above `late_s` on arrival, same clock only),
skipped (superseded before the consumer took them) and corrupt (bad magic, version, length,
header CRC or image: dropped, never raised). Only the header is checked on arrival (and,
with a key, the pixel digest); the image is decoded when the consumer takes the frame, so a
JPEG that does not decode and is superseded first counts as skipped.

The publisher writes each frame once: `frame_buffer()` hands out the (H, W, 3) pixel region of
the payload that will be sent (one payload, drawn into again for every frame; the renderer
draws into it: `FastRenderer.render(..., out=)`), `publish` writes the header in place
(stamped once, at the put; signed: the pixel digest and the MAC first) and copies the payload
into a buffer of the publisher's shared-memory pool (`shm_frames`; zenoh-python 1.10's
`ZShmMut` takes bytes or a bytearray, not a writable view, so this one copy remains). With
`shm_frames=0` the payload is put as is and Zenoh's transport optimisation copies it into its
own pool: less CPU per frame, but frames dropped under DROP congestion control (seen in
tests/perception/test_perception_transport.py's two-process test, 2 runs in 15), so it is not the default.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import hmac
import json
import logging
import math
import os
import re
import struct
import threading
import time
import zlib
from dataclasses import asdict, dataclass, field

import cv2
import numpy as np

from skyherd.perception.camera import CameraParams
from skyherd.runio.mac import record_ok, sign_record
from skyherd.runio.ports import ZENOH_BASE

log = logging.getLogger(__name__)

_HDR = struct.Struct("<4sHBBIQdd3d4dHHI16s16sI")
HEADER_LEN = _HDR.size
_CRC_AT = HEADER_LEN - 4  # the header CRC covers the header before it
_CRC = struct.Struct("<I")
MAGIC = b"SKYF"
VERSION = 5  # plain: header CRC
VERSION_SIGNED = 6  # pixel digest: AES-GMAC under the flight key's pixel key; MAC trailer
RETIRED_VERSIONS = {3: "plain, a checksum of the pixels", 4: "signed, a Poly1305 pixel digest"}
NONCE_LEN = DIGEST_LEN = 16
MAC_LEN = 32
TRAILER_LEN = MAC_LEN  # signed frames only
RAW, JPEG = 0, 1
ENCODINGS = {"raw": RAW, "jpeg": JPEG}
DEFAULT_PORT = ZENOH_BASE  # instance 0's; instance N: runio.ports.zenoh_port(N)
_NO_NONCE = bytes(NONCE_LEN)
_NO_DIGEST = bytes(DIGEST_LEN)


def frame_key(vehicle: str) -> str:
    return f"skyherd/{vehicle}/camera/frame"


def info_key(vehicle: str) -> str:
    return f"skyherd/{vehicle}/camera/info"


class CorruptFrame(ValueError):
    """A payload that is not a valid frame."""


class RefusedFrame(CorruptFrame):
    """A frame that fails authentication (unsigned, or a wrong MAC or pixel digest)."""


def frame_mac(key: bytes, header: bytes) -> bytes:
    """The MAC of a signed frame: BLAKE2b-256 keyed with the flight key over its header."""
    return hashlib.blake2b(header, key=key, digest_size=MAC_LEN).digest()


@functools.lru_cache(maxsize=4)
def _pixel_cipher(key: bytes):
    """AES-256-GCM under the flight key's pixel key: BLAKE2b-256 keyed with the flight key
    (made once per key: its key schedule is not paid per frame)."""
    from cryptography.hazmat.primitives.ciphers.aead import AESGCM

    return AESGCM(hashlib.blake2b(key=key, digest_size=32, person=b"skyherd-px-gmac").digest())


def pixel_digest(key: bytes, nonce: bytes, data) -> bytes:
    """The 16-byte digest of a signed frame's pixel bytes `data` (any buffer, not copied): the
    AES-GMAC tag (AES-256-GCM's tag over `data` as associated data, nothing encrypted) under
    the flight key's pixel key, with the first 12 bytes of the frame's `nonce` as the IV."""
    return _pixel_cipher(key).encrypt(nonce[:12], b"", data)


def _write_header(payload: bytearray, seq, t_sim, pos_ned, quat, width, height, n, encoding,
                  stream, t_pub, nonce, digest, signed) -> None:  # fmt: skip
    """Write the header and its CRC into the first HEADER_LEN bytes of `payload`; t_pub None:
    now (wall clock)."""
    p, q = pos_ned, quat
    _HDR.pack_into(
        payload, 0, MAGIC, VERSION_SIGNED if signed else VERSION, encoding, 0,
        stream & 0xFFFFFFFF, seq, float(t_sim), time.time() if t_pub is None else t_pub,
        float(p[0]), float(p[1]), float(p[2]), float(q[0]), float(q[1]), float(q[2]),
        float(q[3]), width, height, n, nonce, digest, 0,
    )  # fmt: skip
    _CRC.pack_into(payload, _CRC_AT, zlib.crc32(memoryview(payload)[:_CRC_AT]))


@dataclass(frozen=True)
class Frame:
    """One received camera frame. image (H, W, 3) uint8 RGB."""

    stream: int
    seq: int
    t_sim: float
    t_pub: float
    pos_ned: np.ndarray
    quat: np.ndarray
    image: np.ndarray
    encoding: int
    t_recv: float = 0.0

    @property
    def latency_s(self) -> float:
        """Publish → receive [s] on the wall clock (meaningful on one machine)."""
        return self.t_recv - self.t_pub


def encode_pixels(image: np.ndarray, encoding: int = RAW, jpeg_quality: int = 90) -> bytes:
    """The pixel part of a frame. image (H, W, 3) uint8 RGB."""
    img = np.ascontiguousarray(image, dtype=np.uint8)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got {img.shape}")
    if encoding == RAW:
        return img.tobytes()
    if encoding == JPEG:
        ok, buf = cv2.imencode(
            ".jpg", cv2.cvtColor(img, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality]
        )
        if not ok:
            raise ValueError("JPEG encoding failed")
        return buf.tobytes()
    raise ValueError(f"unknown encoding {encoding}")


def seal(payload: bytearray, seq: int, t_sim: float, pos_ned, quat, width: int, height: int,
         encoding: int = RAW, stream: int = 0, t_pub: float | None = None,
         key: bytes | None = None) -> bytearray:  # fmt: skip
    """Finish a frame in place: `payload` is HEADER_LEN bytes of room, the pixel data, and with
    `key` TRAILER_LEN bytes of room. Writes the header (publish time: now, unless `t_pub`);
    signed, computes the pixel digest first (the one pass over the pixels) and writes the MAC
    trailer after. Returns payload."""
    n = len(payload) - HEADER_LEN - (TRAILER_LEN if key is not None else 0)
    nonce, digest = _NO_NONCE, _NO_DIGEST
    if key is not None:
        nonce = os.urandom(NONCE_LEN)
        digest = pixel_digest(key, nonce, memoryview(payload)[HEADER_LEN : HEADER_LEN + n])
    _write_header(payload, seq, t_sim, pos_ned, quat, width, height, n, encoding, stream, t_pub,
                  nonce, digest, key is not None)  # fmt: skip
    if key is not None:
        payload[HEADER_LEN + n :] = frame_mac(key, memoryview(payload)[:HEADER_LEN])
    return payload


def restamp(payload: bytearray, key: bytes | None = None) -> None:
    """Set a sealed payload's publish time to now: its header CRC and (signed, `key`) its MAC
    again; the pixels and their digest are unchanged."""
    f = list(_HDR.unpack_from(payload))
    f[7] = time.time()
    _HDR.pack_into(payload, 0, *f)
    _CRC.pack_into(payload, _CRC_AT, zlib.crc32(memoryview(payload)[:_CRC_AT]))
    if key is not None:
        payload[len(payload) - MAC_LEN :] = frame_mac(key, memoryview(payload)[:HEADER_LEN])


def encode_frame(
    seq: int,
    t_sim: float,
    pos_ned: np.ndarray,
    quat: np.ndarray,
    image: np.ndarray,
    encoding: int = RAW,
    stream: int = 0,
    jpeg_quality: int = 90,
    t_pub: float | None = None,
    key: bytes | None = None,
) -> bytes:
    """Frame → bytes (header + pixels; with `key`, signed: version 6 + the trailer).
    image (H, W, 3) uint8 RGB. The publish time is stamped after the pixels are encoded and
    digested, so latency measures the link, not the encoder."""
    data = encode_pixels(image, encoding, jpeg_quality)
    h, w = np.shape(image)[:2]
    payload = bytearray(HEADER_LEN) + data + bytearray(TRAILER_LEN if key is not None else 0)
    return bytes(seal(payload, seq, t_sim, pos_ned, quat, w, h, encoding, stream, t_pub, key))


@dataclass(frozen=True)
class FrameHeader:
    """A frame's header, parsed and checked without touching the pixels (done for every
    arrival)."""

    stream: int
    seq: int
    t_sim: float
    t_pub: float
    pos_ned: np.ndarray
    quat: np.ndarray
    width: int
    height: int
    encoding: int
    data_len: int
    digest: bytes  # of the pixels: AES-GMAC (signed) or zeros (plain)
    t_recv: float
    nonce: bytes = _NO_NONCE  # the digest's (signed)
    # the flight key to check the digest with (None: plain, no key, or checked already); never
    # in a repr, so never in a log
    check_key: bytes | None = field(default=None, repr=False)
    signed: bool = False  # the digest was keyed from the flight key and the MAC checked

    @property
    def latency_s(self) -> float:
        return self.t_recv - self.t_pub


def decode_header(
    payload: bytes, t_recv: float | None = None, key: bytes | None = None
) -> FrameHeader:
    """Header fields; a short payload, bad magic/version/length/header CRC or non-finite pose
    raise CorruptFrame. With `key`: a plain frame or a MAC that fails raise RefusedFrame (the
    pixels are checked against the digest later: pixel_data)."""
    if len(payload) < HEADER_LEN:
        raise CorruptFrame(f"payload of {len(payload)} bytes is shorter than the header")
    f = _HDR.unpack_from(payload)
    magic, version, enc, _, stream, seq, t_sim, t_pub = f[:8]
    pos, quat = np.array(f[8:11]), np.array(f[11:15])
    w, h, n, nonce, digest, crc = f[15:21]
    if magic != MAGIC:
        raise CorruptFrame(f"bad magic {magic!r}")
    if version in RETIRED_VERSIONS:
        raise CorruptFrame(f"frame version {version} ({RETIRED_VERSIONS[version]}) is no longer "
                           f"read: plain {VERSION}, signed {VERSION_SIGNED}")  # fmt: skip
    if version not in (VERSION, VERSION_SIGNED):
        raise CorruptFrame(f"unknown frame version {version}")
    signed = version == VERSION_SIGNED
    if key is not None and not signed:
        raise RefusedFrame("unsigned frame on an authenticated link")
    trailer = TRAILER_LEN if signed else 0
    if len(payload) - HEADER_LEN - trailer != n:
        raise CorruptFrame(f"data length {len(payload) - HEADER_LEN - trailer} != header's {n}")
    head = memoryview(payload)[:HEADER_LEN]
    if key is not None:
        mac = bytes(payload[HEADER_LEN + n : HEADER_LEN + n + MAC_LEN])
        if not hmac.compare_digest(mac, frame_mac(key, head)):
            raise RefusedFrame("frame MAC does not match the flight key")
    elif zlib.crc32(head[:_CRC_AT]) != crc:
        raise CorruptFrame("header CRC mismatch")
    if not (np.isfinite(pos).all() and np.isfinite(quat).all() and math.isfinite(t_sim)):
        raise CorruptFrame("non-finite pose or time")
    if enc not in (RAW, JPEG):
        raise CorruptFrame(f"unknown encoding {enc}")
    t_recv = time.time() if t_recv is None else t_recv
    return FrameHeader(stream, seq, t_sim, t_pub, pos, quat, w, h, enc, n, digest, t_recv, nonce,
                       key, key is not None)  # fmt: skip


def pixel_data(hdr: FrameHeader, payload: bytes) -> memoryview:
    """The pixel bytes of a payload whose header is `hdr`; a signed frame read with the key is
    checked against its digest (RefusedFrame), any other frame has none to check."""
    data = memoryview(payload)[HEADER_LEN : HEADER_LEN + hdr.data_len]
    if hdr.check_key is not None and not hmac.compare_digest(
        pixel_digest(hdr.check_key, hdr.nonce, data), hdr.digest
    ):
        raise RefusedFrame("pixels do not match the signed digest")
    return data


def decode_pixels(hdr: FrameHeader, payload: bytes) -> Frame:
    """Check the pixels against the digest (pixel_data) and decode the image of a payload
    whose header is `hdr`."""
    data = pixel_data(hdr, payload)
    w, h = hdr.width, hdr.height
    if hdr.encoding == RAW:
        if hdr.data_len != w * h * 3:
            raise CorruptFrame(f"raw size {hdr.data_len} != {w}x{h}x3")
        img = np.frombuffer(data, dtype=np.uint8).reshape(h, w, 3)
    else:
        bgr = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
        if bgr is None or bgr.shape[:2] != (h, w):
            raise CorruptFrame("JPEG does not decode to the header's size")
        img = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    return Frame(
        hdr.stream, hdr.seq, hdr.t_sim, hdr.t_pub, hdr.pos_ned, hdr.quat, img, hdr.encoding,
        hdr.t_recv,
    )  # fmt: skip


def decode_frame(payload: bytes, t_recv: float | None = None, key: bytes | None = None) -> Frame:
    """bytes → Frame; anything malformed raises CorruptFrame (with `key`, anything not
    authentic RefusedFrame, a CorruptFrame)."""
    return decode_pixels(decode_header(payload, t_recv, key), payload)


def camera_info(cam: CameraParams, encoding: str, mount: str = "body") -> dict:
    """The camera_info record (JSON-able): intrinsics, mounting (the camera on the body, and how
    the body carries it: hil.camera_mount's body / level / pointed), pixel convention."""
    return {
        "width_px": cam.width_px,
        "height_px": cam.height_px,
        "fx_px": cam.fx,
        "fy_px": cam.fx,
        "cx_px": cam.cx,
        "cy_px": cam.cy,
        "hfov_rad": cam.hfov_rad,
        "mount_pitch_rad": cam.mount_pitch_rad,
        "mount_offset_frd_m": list(cam.mount_offset_frd),
        "mount": mount,
        "encoding": encoding,
        "pixels": "RGB, row 0 at the top; integer (u, v) is a pixel centre",
    }


# -- sessions ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ZenohParams:
    """How to open the Zenoh session (see the module docstring)."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()
    multicast_scouting: bool = False
    shared_memory: bool = True  # frames between processes on this machine skip the TCP copy
    config_file: str | None = None  # a Zenoh JSON5 config; replaces everything above


def publisher_params(port: int = DEFAULT_PORT) -> ZenohParams:
    """Default for the frame source: a peer listening on loopback only."""
    return ZenohParams(listen=(f"tcp/127.0.0.1:{port}",))


def subscriber_params(connect: str | None = None, port: int = DEFAULT_PORT) -> ZenohParams:
    """Default for a viewer: a peer that connects to the source on loopback."""
    return ZenohParams(connect=(connect or f"tcp/127.0.0.1:{port}",))


def viewer_params(connect: str | None, config_file: str | None = None) -> ZenohParams:
    """A viewer's session: the Zenoh config file if one is given, else a peer that connects to
    `connect` (the one address syntax, runio.address: tcp:HOST:PORT, or Zenoh's tcp/HOST:PORT);
    runio.AddressError for a bad address."""
    from skyherd.runio.address import zenoh_endpoint

    if config_file:
        return ZenohParams(config_file=config_file)
    return subscriber_params(zenoh_endpoint(connect))


def open_session(p: ZenohParams):
    """Open a Zenoh session. Bad endpoints or config files raise ValueError with the reason."""
    import zenoh

    try:
        if p.config_file:
            if not os.path.exists(p.config_file):
                raise ValueError(f"Zenoh config file {p.config_file} does not exist")
            conf = zenoh.Config.from_file(p.config_file)
        else:
            conf = zenoh.Config()
            conf.insert_json5("mode", json.dumps(p.mode))
            conf.insert_json5("listen/endpoints", json.dumps(list(p.listen)))
            conf.insert_json5("connect/endpoints", json.dumps(list(p.connect)))
            conf.insert_json5(
                "scouting/multicast/enabled", "true" if p.multicast_scouting else "false"
            )
            conf.insert_json5(
                "transport/shared_memory/enabled", "true" if p.shared_memory else "false"
            )
        return zenoh.open(conf)
    except zenoh.ZError as e:
        where = p.config_file or ", ".join((*p.listen, *p.connect)) or "no endpoint"
        raise ValueError(f"cannot open a Zenoh session ({where}): {zenoh_error_text(e)}") from e


def open_viewer(connect: str | None, config_file: str | None = None):
    """A viewer's (ZenohParams, open session) (viewer_params, open_session); ValueError, one
    line naming --connect or --zenoh-config, otherwise."""
    from skyherd.runio.address import AddressError

    try:
        p = viewer_params(connect, config_file)
    except AddressError as e:
        raise ValueError(f"--connect {e}") from None
    try:
        return p, open_session(p)
    except ValueError as e:  # said again with the option's name, Zenoh's own reason once
        where = f"--zenoh-config {config_file}" if config_file else f"--connect {connect}"
        reason = zenoh_error_text(e.__cause__) if e.__cause__ is not None else str(e)
        raise ValueError(f"cannot open a Zenoh session ({where}): {reason}") from None


def zenoh_error_text(e: Exception) -> str:
    """A Zenoh (Rust) error as one readable line: its message without the Rust source
    locations ("at /root/.cargo/.../tcp.rs:61.") and without line breaks."""
    text = str(e)
    m = re.search(r'msg: "([^"]*)"', text)
    text = m.group(1) if m else text
    text = re.sub(r"\s+at\s+/\S+?\.rs:\d+\.?", "", text)
    return " ".join(text.split()).strip()


# -- publisher ---------------------------------------------------------------------------


class FramePublisher:
    """Publishes frames (and camera info) for one vehicle on an open session."""

    def __init__(
        self,
        session,
        vehicle: str,
        cam: CameraParams,
        encoding: str = "raw",
        jpeg_quality: int = 90,
        info_every: int = 30,
        rng: np.random.Generator | None = None,
        shm_frames: int = 8,
        mount: str = "body",
        key: bytes | None = None,
    ):
        import zenoh

        if encoding not in ENCODINGS:
            raise ValueError(f"encoding must be raw or jpeg, got {encoding!r}")
        self.cam, self.encoding, self.jpeg_quality = cam, encoding, jpeg_quality
        self.mount = mount  # how the vehicle carries the camera (camera_info)
        self.key = key  # the flight key: frames signed (version 6 + trailer), else version 5
        self.info_every = max(1, info_every)
        self.stream = int((rng or np.random.default_rng()).integers(1, 2**32 - 1))
        self.seq = 0
        self._pub = session.declare_publisher(
            frame_key(vehicle),
            congestion_control=zenoh.CongestionControl.DROP,
            priority=zenoh.Priority.DATA_HIGH,
            express=True,
        )
        self._info = session.declare_publisher(info_key(vehicle))
        # a shared-memory pool of its own, in frames (0: none; Zenoh's transport optimisation
        # then carries each frame through its own pool: less CPU, but under DROP congestion
        # control more frames dropped, bench_frames.py / docs/perception.md)
        self._shm_frames = shm_frames
        self._shm = None  # zenoh.shm.ShmProvider, made at the first frame (its size is known then)
        self._gc = None  # its allocation policy (zenoh.shm.GarbageCollect)
        self.shm_fallbacks = 0  # frames sent by copy because shared memory was not available
        self.shm_error: str | None = None  # why shared memory is off (_shm_off), if it is
        self._last: bytearray | None = None  # the last payload sent (republish)
        # raw frames: one payload, filled again for each frame (its pages stay hot: a second one,
        # alternately filled, cost ~0.02 ms per 640x480 frame in the bench), with its (H, W, 3)
        # pixel view; `_drawing`: handed out by frame_buffer() since the last publish, so the
        # last frame in it may be half overwritten (republish waits for the next publish)
        self._frame: tuple[bytearray, np.ndarray] | None = None
        self._drawing = False

    def frame_buffer(self, height: int | None = None, width: int | None = None) -> np.ndarray:
        """The (H, W, 3) uint8 pixels of the payload the next raw frame is sent in (default:
        the camera's size). Render into it and pass it to `publish`: no copy is made. It is the
        buffer of the last raw frame: from this call until the next `publish`, `republish` sends
        nothing."""
        h = self.cam.height_px if height is None else height
        w = self.cam.width_px if width is None else width
        if self._frame is None or self._frame[1].shape[:2] != (h, w):
            trailer = TRAILER_LEN if self.key is not None else 0
            payload = bytearray(HEADER_LEN + h * w * 3 + trailer)
            view = np.frombuffer(payload, np.uint8, h * w * 3, HEADER_LEN).reshape(h, w, 3)
            self._frame = (payload, view)
        self._drawing = True
        return self._frame[1]

    def _raw_payload(self, image: np.ndarray) -> bytearray:
        """The next raw payload with `image` as its pixels (copied unless it is frame_buffer())."""
        img = np.asarray(image)
        if img.ndim != 3 or img.shape[2] != 3:
            raise ValueError(f"expected an (H, W, 3) image, got {img.shape}")
        view = self.frame_buffer(*img.shape[:2])
        if img is not view:  # not rendered into frame_buffer()
            view[...] = img
        return self._frame[0]

    def _put(self, payload: bytearray) -> None:
        """Send one payload through a shared-memory buffer when possible (a subscriber in
        another process on this machine maps it instead of receiving a TCP copy), else by
        copy."""
        import zenoh

        n = len(payload)
        if self._shm is None and self._shm_frames > 0:
            try:
                self._shm = zenoh.shm.ShmProvider.default_backend(self._shm_frames * n)
                self._gc = zenoh.shm.GarbageCollect()
            except BaseException as e:  # no /dev/shm, too small a limit: copy instead
                self._shm_off(e)
        if self._shm is not None:
            try:
                buf = self._shm.alloc(n, policy=self._gc)
            except Exception:  # noqa: BLE001 - pool exhausted by slow readers: copy this one
                self.shm_fallbacks += 1
            except BaseException as e:  # the segment could not be made: copy from now on
                self._shm_off(e)
                self.shm_fallbacks += 1
            else:
                buf[0:n] = payload
                self._pub.put(buf)
                return
        self._pub.put(payload)

    def _shm_off(self, e: BaseException) -> None:
        """Shared memory off for the rest of the flight, frames sent by copy, the reason kept
        (`shm_error`) and said once. Zenoh reports a segment it cannot make (e.g. its pages
        cannot be locked: RLIMIT_MEMLOCK, 8 MiB for a user without CAP_IPC_LOCK, is less than
        `shm_frames` 640×480 frames) as a Rust panic, which pyo3 raises as a BaseException:
        any other BaseException (KeyboardInterrupt, SystemExit) goes on."""
        if not isinstance(e, Exception) and type(e).__name__ != "PanicException":
            raise e
        self._shm, self._gc, self._shm_frames = None, None, 0
        self.shm_error = f"{type(e).__name__}: {e}"
        log.warning("camera frames: shared memory off, frames sent by copy (%s)", self.shm_error)

    def publish(
        self, t_sim: float, uav_pos_ned: np.ndarray, uav_quat: np.ndarray, image: np.ndarray
    ) -> int:
        """Send one frame; returns its sequence number. `image` (H, W, 3) uint8 RGB: ideally
        `frame_buffer()` rendered into (raw encoding: then nothing is copied before the put)."""
        if self.seq % self.info_every == 0:
            self.publish_info(t_sim)
        enc = ENCODINGS[self.encoding]
        h, w = np.shape(image)[:2]
        if enc == RAW:
            payload = self._raw_payload(image)
        else:
            data = encode_pixels(image, enc, self.jpeg_quality)
            payload = bytearray(HEADER_LEN) + data
            payload += bytes(TRAILER_LEN if self.key is not None else 0)
        seal(payload, self.seq, t_sim, uav_pos_ned, uav_quat, w, h, enc, self.stream,
             key=self.key)  # fmt: skip
        self._put(payload)
        self._last, self._drawing = payload, False
        self.seq += 1
        return self.seq - 1

    def republish(self) -> bool:
        """Send the last frame again, same sequence number and pixels, stamped now (a
        subscriber that has it drops the copy as out of order). Lockstep uses it while it waits
        for a late subscriber. Returns whether it was sent: not before the first frame, nor
        while the last frame's buffer is being drawn into (frame_buffer() since)."""
        if self._last is None or (self._drawing and self._last is self._frame[0]):
            return False
        restamp(self._last, self.key)
        self._put(self._last)
        return True

    def has_subscriber(self) -> bool:
        """Whether a subscriber to the frame key is reachable (Zenoh matching status)."""
        return bool(self._pub.matching_status.matching)

    def wait_for_subscriber(self, timeout_s: float) -> bool:
        """Block up to `timeout_s` [s] until a subscriber matches; returns whether one did."""
        deadline = time.monotonic() + timeout_s
        while not self.has_subscriber():
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def publish_info(self, t_sim: float) -> None:
        rec = {**camera_info(self.cam, self.encoding, self.mount), "t_sim": t_sim,
               "stream": self.stream}  # fmt: skip
        self._info.put(sign_record(rec, self.key))  # with the key: its "mac" (runio.mac)

    def close(self) -> None:
        for p in (self._pub, self._info):
            try:
                p.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass


# -- subscriber --------------------------------------------------------------------------


@dataclass
class LinkStats:
    received: int = 0
    lost: int = 0
    out_of_order: int = 0
    repeated: int = 0  # the last frame again: re-published while the simulator waits for a close
    late: int = 0
    skipped: int = 0
    corrupt: int = 0
    refused: int = 0  # not authentic (with a key): unsigned, wrong MAC or pixel digest
    info_received: int = 0
    info_corrupt: int = 0
    info_refused: int = 0  # camera info without a valid "mac" (with a key)
    latencies_s: list[float] = field(default_factory=list, repr=False)

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("latencies_s")
        return d


class FrameSubscriber:
    """Receives frames for one vehicle; always offers the newest one.

    `take()` returns the newest frame not yet taken (or None); `wait(timeout_s)` blocks for one.
    On arrival (Zenoh's thread) only the header is parsed and the books kept; the CRC check and
    the pixel decoding happen when the consumer takes the frame, so only frames that are used
    cost a decode, and a slow consumer never backs up the link. A frame that fails there counts
    as corrupt and is dropped (take() then returns None).
    """

    def __init__(self, session, vehicle: str, late_s: float = 0.1, keep_latencies: int = 100000,
                 key: bytes | None = None):  # fmt: skip
        self.key = key  # the flight key: only authentic frames (module docstring)
        self.stats = LinkStats()
        self.late_s = late_s
        self.keep_latencies = keep_latencies
        self.info: dict | None = None
        self._cv = threading.Condition()
        self._latest: Frame | None = None
        self._pending: tuple[FrameHeader, bytes] | None = None
        self._taken = True
        self._stream: int | None = None
        self._last_seq = -1
        self._last_t_pub: float | None = None  # the last frame taken's publish stamp
        self._sub = session.declare_subscriber(frame_key(vehicle), self._on_frame)
        self._sub_info = session.declare_subscriber(info_key(vehicle), self._on_info)

    def _on_frame(self, sample) -> None:
        t_recv = time.time()
        payload = sample.payload.to_bytes()
        try:
            hdr = decode_header(payload, t_recv, self.key)
            if hdr.signed:  # authentic before the books: the pixels too (one cheap pass)
                pixel_data(hdr, payload)
                hdr = dataclasses.replace(hdr, check_key=None)  # checked: not again at take
        except RefusedFrame:
            with self._cv:
                self.stats.refused += 1
            return
        except (CorruptFrame, struct.error):
            with self._cv:
                self.stats.corrupt += 1
            return
        self._accept(hdr, payload)

    def on_frame(self, fr: Frame) -> None:
        """Book-keeping for one decoded frame (public so that it can be tested without a link)."""
        self._accept(fr, fr)

    def _accept(self, hdr, body) -> None:
        with self._cv:
            s = self.stats
            if hdr.stream != self._stream:  # new publisher (or a restart): start afresh
                self._stream, self._last_seq = hdr.stream, hdr.seq - 1
            if hdr.seq == self._last_seq and hdr.t_pub == self._last_t_pub:
                s.repeated += 1  # the same frame re-sent (lockstep patience): nothing new
                return
            if hdr.seq <= self._last_seq:
                s.out_of_order += 1
                if s.lost > 0 and hdr.seq < self._last_seq:
                    s.lost -= 1
                return
            s.received += 1
            s.lost += hdr.seq - self._last_seq - 1
            if not self._taken:
                s.skipped += 1
            if hdr.latency_s > self.late_s:
                s.late += 1
            if len(s.latencies_s) < self.keep_latencies:
                s.latencies_s.append(hdr.latency_s)
            self._last_seq, self._last_t_pub = hdr.seq, hdr.t_pub
            if isinstance(body, Frame):
                self._latest, self._pending = body, None
            else:
                self._pending = (hdr, body)
            self._taken = False
            self._cv.notify_all()

    def _on_info(self, sample) -> None:
        try:
            info = json.loads(sample.payload.to_bytes().decode())
            if not isinstance(info, dict) or "width_px" not in info:
                raise ValueError("not a camera info record")
        except (ValueError, UnicodeDecodeError):
            with self._cv:
                self.stats.info_corrupt += 1
            return
        if self.key is not None and not record_ok(info, self.key):
            with self._cv:
                self.stats.info_refused += 1
            return
        with self._cv:
            self.info = info
            self.stats.info_received += 1

    def _resolve(self) -> Frame | None:
        """Decode the pending payload (lock held): the new frame, or None when it is corrupt
        (counted; `_latest` keeps the last good frame)."""
        if self._pending is None:
            return self._latest
        hdr, payload = self._pending
        self._pending = None
        try:
            self._latest = decode_pixels(hdr, payload)
        except RefusedFrame:
            self.stats.refused += 1
            self.stats.received -= 1
            return None
        except (CorruptFrame, cv2.error, ValueError):
            self.stats.corrupt += 1
            self.stats.received -= 1
            return None
        return self._latest

    def latest(self) -> Frame | None:
        """The newest good frame received (taken or not), or None."""
        with self._cv:
            self._resolve()
            return self._latest

    def take(self) -> Frame | None:
        with self._cv:
            if self._taken:
                return None
            self._taken = True
            return self._resolve()

    def wait(self, timeout_s: float) -> Frame | None:
        """The newest untaken frame, waiting up to `timeout_s` [s] for one (None on timeout)."""
        deadline = time.monotonic() + timeout_s
        with self._cv:
            while self._taken:
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self._cv.wait(left)
            self._taken = True
            return self._resolve()

    def close(self) -> None:
        for s in (self._sub, self._sub_info):
            try:
                s.undeclare()
            except Exception:  # noqa: BLE001 - already closed with its session
                pass
