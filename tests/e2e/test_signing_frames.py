"""Issue 27 item 3: camera frames authenticated with the flight's key (perception/transport.py).

The wire format both ways (signed frames verify; unsigned, wrong-key, tampered-header and
tampered-pixel frames are refused, and a keyless reader still reads a signed frame), a forged
next frame over real Zenoh that never reaches the subscriber's books, and a real attacker
process (tests/attacker.py) forging the camera's next frame against a default `skyherd fly`
(no effect) and a `--no-signing` one (taken as input)."""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest
from test_attack_mavlink import assert_signed_and_untouched, assert_unsigned, attacked_flight

from skyherd.perception.transport import (
    RAW,
    FramePublisher,
    FrameSubscriber,
    RefusedFrame,
    decode_frame,
    decode_header,
    encode_frame,
    open_session,
    publisher_params,
    subscriber_params,
)

KEY, OTHER = os.urandom(32), os.urandom(32)
IMG = (np.arange(48 * 64 * 3) % 251).astype(np.uint8).reshape(48, 64, 3)
POS, QUAT = np.array([1.0, 2.0, -30.0]), np.array([1.0, 0.0, 0.0, 0.0])


def test_signed_frames_verify_and_keyless_readers_still_read_them():
    signed = encode_frame(7, 1.25, POS, QUAT, IMG, RAW, stream=9, key=KEY)
    f = decode_frame(signed, key=KEY)
    assert (f.seq, f.t_sim, f.stream) == (7, 1.25, 9) and np.array_equal(f.image, IMG)
    g = decode_frame(signed)  # the recorder, a viewer: no key, same frame
    assert np.array_equal(g.image, IMG)
    plain = encode_frame(7, 1.25, POS, QUAT, IMG, RAW, stream=9)
    assert len(signed) == len(plain) + 32 and decode_frame(plain).seq == 7  # + the MAC trailer


@pytest.mark.parametrize(
    "make,why",
    [
        (lambda: encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9), "unsigned"),
        (lambda: encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=OTHER), "MAC"),
        (lambda: _flip(encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=KEY), 20), "MAC"),
    ],
)
def test_unsigned_wrong_key_and_tampered_headers_are_refused_on_arrival(make, why):
    with pytest.raises(RefusedFrame, match=why):
        decode_header(make(), key=KEY)


def test_a_header_that_passes_its_mac_with_pixels_not_its_own_is_refused_at_take():
    """The CRC is no authentication (anyone can recompute it); the signed digest is: pixels
    whose AES-GMAC tag differs from the MAC'd digest are refused when the frame is decoded."""
    import dataclasses

    from skyherd.perception.transport import decode_pixels

    payload = encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=KEY)
    hdr = decode_header(payload, key=KEY)
    assert np.array_equal(decode_pixels(hdr, payload).image, IMG)
    with pytest.raises(RefusedFrame, match="digest"):
        decode_pixels(dataclasses.replace(hdr, digest=bytes(32)), payload)


@pytest.mark.parametrize("where", ["first", "middle", "last"])
def test_a_flipped_pixel_byte_is_refused(where):
    """One pixel byte altered on the way (the header and its MAC untouched): the header passes
    on arrival, the frame is refused when taken (signed). A plain frame (version 5) has no
    pixel digest: its header CRC passes and the altered pixel is read as sent (integrity over
    the header only; the pixels are the link's, and authenticity is the signed frame's)."""
    from skyherd.perception.transport import HEADER_LEN, decode_pixels

    n = IMG.size
    i = HEADER_LEN + {"first": 0, "middle": n // 2, "last": n - 1}[where]
    signed = _flip(encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=KEY), i)
    hdr = decode_header(signed, key=KEY)  # the header and its MAC are the sender's
    with pytest.raises(RefusedFrame, match="digest"):
        decode_pixels(hdr, signed)
    with pytest.raises(RefusedFrame):
        decode_frame(signed, key=KEY)
    plain = _flip(encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9), i)
    altered = decode_frame(plain).image
    assert (
        np.count_nonzero(altered != IMG) == 1
        and altered.flat[i - HEADER_LEN] == IMG.flat[i - HEADER_LEN] ^ 1
    )


def test_a_flipped_pixel_byte_over_zenoh_is_refused_and_the_good_frame_kept():
    """A forger without the key sends a real signed frame with one pixel byte altered first
    (same header, same MAC): the subscriber with the key refuses it on arrival, keeps the last
    good frame, and takes the real frame of that number when it comes."""
    port = 7495
    from skyherd.perception.camera import CameraParams

    pub_s = open_session(publisher_params(port))
    sub_s = open_session(subscriber_params(port=port))
    try:
        cam = CameraParams(width_px=64, height_px=48)
        pub = FramePublisher(pub_s, "uav0", cam, key=KEY)
        guarded = FrameSubscriber(sub_s, "uav0", key=KEY)
        forger = pub_s.declare_publisher("skyherd/uav0/camera/frame")
        assert pub.wait_for_subscriber(30.0)
        buf = pub.frame_buffer()
        buf[...] = IMG  # rendered into the published buffer
        pub.publish(0.0, POS, QUAT, buf)
        assert np.array_equal(guarded.wait(30.0).image, IMG)
        real = encode_frame(1, 0.1, POS, QUAT, IMG, RAW, stream=pub.stream, key=KEY)
        from skyherd.perception.transport import HEADER_LEN

        forger.put(_flip(real, HEADER_LEN + 100))
        deadline = time.monotonic() + 30.0
        while guarded.stats.refused < 1:  # refused on arrival: never in the books
            assert time.monotonic() < deadline, guarded.stats
            time.sleep(0.01)
        assert guarded.take() is None and guarded.latest().seq == 0
        forger.put(real)  # the same frame, unaltered, after it: taken (not out of order)
        f = guarded.wait(30.0)
        assert f is not None and f.seq == 1 and np.array_equal(f.image, IMG)
        for s in (guarded, pub):
            s.close()
    finally:
        sub_s.close()
        pub_s.close()


def _flip(b: bytes, i: int) -> bytes:
    return b[:i] + bytes([b[i] ^ 1]) + b[i + 1 :]


def test_the_pixel_digest_is_aes_gmac_under_the_flight_keys_pixel_key_and_a_fresh_iv():
    """Version 6's digest, computed apart from the transport: AES-256-GCM's tag over the pixels
    as associated data, nothing encrypted, under BLAKE2b-256 keyed with the flight key
    (person "skyherd-px-gmac"), IV the first 12 bytes of the frame's nonce. Two frames of the
    same pixels get other nonces, so other digests (no IV used twice)."""
    import hashlib

    from cryptography.hazmat.primitives.ciphers.aead import AESGCM

    from skyherd.perception.transport import HEADER_LEN, VERSION_SIGNED

    a, b = (encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=KEY) for _ in range(2))
    ha, hb = decode_header(a, key=KEY), decode_header(b, key=KEY)
    pixel_key = hashlib.blake2b(key=KEY, digest_size=32, person=b"skyherd-px-gmac").digest()
    pixels = a[HEADER_LEN : HEADER_LEN + IMG.size]
    assert int.from_bytes(a[4:6], "little") == VERSION_SIGNED == 6
    assert ha.digest == AESGCM(pixel_key).encrypt(ha.nonce[:12], b"", pixels)
    assert ha.nonce != hb.nonce and ha.digest != hb.digest
    assert ha.check_key == KEY and repr(KEY) not in repr(ha)  # the flight key is never logged


def test_a_digest_made_under_another_flights_key_is_refused_though_the_header_mac_is_good():
    """A header MAC'd with the flight key over a pixel digest computed under another key (as
    one who holds only that other key, or a frame of another flight, could offer): refused."""
    from skyherd.perception.transport import (
        HEADER_LEN,
        MAC_LEN,
        _write_header,
        decode_pixels,
        frame_mac,
        pixel_digest,
    )

    nonce = os.urandom(16)
    payload = bytearray(HEADER_LEN) + IMG.tobytes() + bytearray(MAC_LEN)
    digest = pixel_digest(OTHER, nonce, IMG.tobytes())
    _write_header(payload, 8, 1.35, POS, QUAT, 64, 48, IMG.size, RAW, 9, None, nonce, digest,
                  True)  # fmt: skip
    payload[-MAC_LEN:] = frame_mac(KEY, bytes(payload[:HEADER_LEN]))
    hdr = decode_header(bytes(payload), key=KEY)  # the header is the flight key's
    with pytest.raises(RefusedFrame, match="digest"):
        decode_pixels(hdr, bytes(payload))
    assert np.array_equal(decode_frame(bytes(payload)).image, IMG)  # keyless: read as sent


@pytest.mark.parametrize("version", [3, 4, 7])
def test_frames_of_retired_and_unknown_versions_are_refused_with_their_reason(version):
    """Version 4 (signed, Poly1305 pixel digest) and 3 (plain, a pixel checksum) are no longer
    read, by a reader with the key or without; an unknown version is refused as such."""
    from skyherd.perception.transport import CorruptFrame

    signed = encode_frame(8, 1.35, POS, QUAT, IMG, RAW, stream=9, key=KEY)
    old = signed[:4] + version.to_bytes(2, "little") + signed[6:]
    why = "no longer read" if version in (3, 4) else "unknown frame version 7"
    for key in (KEY, None):
        with pytest.raises(CorruptFrame, match=why):
            decode_frame(old, key=key)


class _Recorder:
    """A Zenoh session stand-in that keeps what is put (FramePublisher with shm_frames=0)."""

    def __init__(self):
        self.sent: list[bytes] = []

    def declare_publisher(self, key, **_):
        rec = self

        class _Pub:
            def put(self, payload):
                if key.endswith("/frame"):
                    rec.sent.append(bytes(payload))

        return _Pub()


def test_a_republished_signed_frame_is_the_sent_one_and_none_goes_while_the_next_is_drawn():
    """The publisher draws each frame into one payload: a republish stamps the last frame anew
    (its MAC still good, its pixels its own); once frame_buffer() has handed that payload out
    for the next frame, republish sends nothing until the next publish."""
    from skyherd.perception.camera import CameraParams

    session = _Recorder()
    pub = FramePublisher(session, "uav0", CameraParams(width_px=64, height_px=48), key=KEY,
                         shm_frames=0)  # fmt: skip
    assert not pub.republish()  # nothing published yet
    buf = pub.frame_buffer()
    buf[...] = IMG
    pub.publish(0.0, POS, QUAT, buf)
    assert pub.republish() and len(session.sent) == 2
    first, again = (decode_frame(b, key=KEY) for b in session.sent)
    assert again.seq == first.seq == 0 and np.array_equal(again.image, IMG)
    assert again.t_pub >= first.t_pub
    buf = pub.frame_buffer()
    buf[:10] = 0  # the next frame half drawn
    assert not pub.republish() and len(session.sent) == 2
    pub.publish(0.1, POS, QUAT, buf)
    assert pub.republish() and len(session.sent) == 4
    assert all(np.array_equal(decode_frame(b, key=KEY).image[:10], 0 * IMG[:10])
               for b in session.sent[2:])  # fmt: skip


def test_forged_next_frame_over_zenoh_never_reaches_the_books():
    """A publisher with the key, a forger without it on the same key expression (same stream
    id, seq + 1, first): the subscriber with the key takes the real frame and counts one
    refused; a keyless subscriber takes the forgery and drops the real one as out of order."""
    port = 7492
    from skyherd.perception.camera import CameraParams

    pub_s = open_session(publisher_params(port))
    sub_s = open_session(subscriber_params(port=port))
    try:
        cam = CameraParams(width_px=64, height_px=48)
        pub = FramePublisher(pub_s, "uav0", cam, key=KEY, shm_frames=0)
        guarded = FrameSubscriber(sub_s, "uav0", key=KEY)
        naive = FrameSubscriber(sub_s, "uav0")
        forger = pub_s.declare_publisher("skyherd/uav0/camera/frame")
        assert pub.wait_for_subscriber(30.0)
        pub.publish(0.0, POS, QUAT, IMG)
        for sub in (guarded, naive):
            assert sub.wait(30.0).seq == 0
        forger.put(encode_frame(1, 0.1, POS, QUAT, np.zeros_like(IMG), RAW, stream=pub.stream))
        deadline = time.monotonic() + 30.0
        while guarded.stats.refused < 1 or naive.stats.received < 2:
            assert time.monotonic() < deadline, (guarded.stats, naive.stats)
            time.sleep(0.01)
        pub.publish(0.1, POS, QUAT, IMG)
        real = guarded.wait(30.0)
        assert real.seq == 1 and np.array_equal(real.image, IMG)
        assert guarded.stats.refused == 1 and guarded.stats.out_of_order == 0
        forged = naive.wait(1.0)
        assert forged is not None and forged.seq == 1 and not forged.image.any()
        while naive.stats.out_of_order < 1:  # the real frame 1: dropped as old
            assert time.monotonic() < deadline, naive.stats
            time.sleep(0.01)
        assert naive.stats.refused == 0
        for s in (guarded, naive):
            s.close()
        pub.close()
    finally:
        sub_s.close()
        pub_s.close()


@pytest.mark.timeout(2400)
@pytest.mark.slow
def test_forged_camera_frames_are_refused_by_a_default_flight_and_taken_without_signing(tmp_path):
    """The attacker answers each real frame with a forged next one (10 of them): with the key
    the companion refuses them and takes every real frame; without, each forgery that arrives
    first takes the real frame's place (the real one is then dropped as out of order)."""
    forge = ("--count", "10")
    rc, run, report = attacked_flight(tmp_path / "signed", "frame", instance=93, zenoh_port=7493,
                                      attacker_args=forge)  # fmt: skip
    assert_signed_and_untouched(rc, run)
    link = json.loads((run / "companion.json").read_text())["camera_link"]
    assert link["authenticated"] is True and link["out_of_order"] == 0, link
    assert link["refused"] == report["sent"] == 10, (link, report)
    rc, run, report = attacked_flight(tmp_path / "unsigned", "frame", "--no-signing",
                                      instance=93, zenoh_port=7493, attacker_args=forge)  # fmt: skip
    assert_unsigned(run)
    link = json.loads((run / "companion.json").read_text())["camera_link"]
    assert link["authenticated"] is False and link["refused"] == 0
    assert report["sent"] == 10 and link["out_of_order"] > 0, (link, report)  # forgeries taken


def test_ugv_states_and_clock_carry_a_mac_and_forged_records_are_refused():
    import json as js

    from skyherd.groundsim.transport import UGVStatePublisher, UGVStateSubscriber
    from skyherd.groundsim.ugv import UGVStates
    from skyherd.runio.mac import record_mac, record_ok, sign_record

    clock = js.loads(sign_record({"t_sim": 1.5}, KEY))
    assert record_ok(clock, KEY) and not record_ok(clock, OTHER)
    assert not record_ok({"t_sim": 1.5}, KEY) and js.loads(sign_record({"t_sim": 1.5}, None)) == {
        "t_sim": 1.5
    }  # unsigned: today's record
    port = 7494
    a = open_session(publisher_params(port))
    b = open_session(subscriber_params(port=port))
    try:
        guarded, naive = UGVStateSubscriber(b, key=KEY), UGVStateSubscriber(b)
        pub = UGVStatePublisher(a, 1, key=KEY)
        forger = a.declare_publisher("skyherd/ugv/0/state")
        deadline = time.monotonic() + 30
        while not forger.matching_status.matching:
            assert time.monotonic() < deadline
            time.sleep(0.02)
        st = UGVStates(np.array([[1.0, 2.0]]), np.array([0.1]), np.array([1.0]), np.array([False]))
        pub.publish(0.1, st)
        fake = {"id": 0, "seq": 1, "t_sim": 0.2, "pos_ned": [500.0, 0.0, 0.0], "heading_rad": 0.0,
                "speed_mps": 0.0, "camouflaged": False}  # fmt: skip
        forger.put(js.dumps(fake).encode())  # no MAC
        forger.put(js.dumps({**fake, "mac": record_mac(OTHER, fake)}).encode())  # wrong key
        while guarded.received + guarded.refused < 3 or naive.received < 3:
            assert time.monotonic() < deadline, (guarded.refused, naive.received)
            time.sleep(0.02)
        assert guarded.refused == 2 and guarded.latest[0]["pos_ned"][0] == 1.0
        assert naive.latest[0]["pos_ned"][0] == 500.0  # without the key the forgery is the state
        for s in (guarded, naive, pub):
            s.close()
    finally:
        b.close()
        a.close()
