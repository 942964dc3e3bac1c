"""skyherd.flight.mavlink.codec's fast decoder against pymavlink's own parser, over the whole dialect."""

from __future__ import annotations

import random
import struct

import pytest
from fastcrc import crc16
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink.codec import (
    _LAYOUTS,
    Codec,
    frame_unsigned_v2,
    pack_unsigned_v2,
    parse_signed_v2,
    parse_unsigned_v2,
)
from skyherd.flight.mavlink.signing import Signing


def frame(cls, payload: bytes, seq: int, sysid: int, compid: int, compat: int = 0) -> bytes:
    n = len(payload)
    while n > 1 and payload[n - 1] == 0:
        n -= 1
    hdr = struct.pack("<BBBBBBBHB", 0xFD, n, 0, compat, seq, sysid, compid, cls.id & 0xFFFF,
                      cls.id >> 16)  # fmt: skip
    body = hdr + payload[:n]
    crc = crc16.mcrf4xx(bytes((cls.crc_extra,)), crc16.mcrf4xx(body[1:]))
    return body + struct.pack("<H", crc)


def slow(datagram: bytes) -> list:
    rx = M.MAVLink(None)
    rx.robust_parsing = True
    return rx.parse_buffer(datagram) or []


def same(a, b) -> bool:
    """Same type and every attribute, in the same order, of the same type and value (NaN and
    -0.0 included: repr): fields, raw char bytes, header, frame bytes and bookkeeping."""
    va, vb = vars(a), vars(b)
    return (
        type(a) is type(b)
        and list(va) == list(vb)
        and all(same_value(va[k], vb[k]) for k in va)
        and repr(a.to_dict()) == repr(b.to_dict())
    )


def same_value(x, y) -> bool:
    if isinstance(x, M.MAVLink_header):
        return type(y) is M.MAVLink_header and list(vars(x).items()) == list(vars(y).items())
    return type(x) is type(y) and repr(x) == repr(y)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_every_message_of_the_dialect_decodes_as_pymavlink_does(seed):
    rng = random.Random(seed)
    classes = list(M.mavlink_map.values())
    for cls in classes:
        size = cls.unpacker.size
        for zeros in (False, True):  # random payloads, and ones ending in zeros (truncated)
            payload = bytearray(rng.randbytes(size))
            if zeros:
                payload[size // 2 :] = bytes(size - size // 2)
            f = frame(cls, bytes(payload), rng.randrange(256), rng.randrange(1, 256),
                      rng.randrange(256), compat=rng.choice((0, 1)))  # fmt: skip
            fast, ref = parse_unsigned_v2(f), slow(f)
            assert fast is not None and len(fast) == len(ref) == 1, cls.msgname
            assert same(fast[0], ref[0]), cls.msgname
        # a payload longer than the dialect's (a newer dialect's extension fields), if it fits
        size = min(size + rng.randrange(1, 9), 255)
        f = frame(cls, rng.randbytes(size - 1) + b"\x01", rng.randrange(256), 1, 1)
        fast, ref = parse_unsigned_v2(f), slow(f)
        assert fast is not None and len(ref) == 1 and same(fast[0], ref[0]), cls.msgname
    # a datagram of many frames, as the vehicle packs a lockstep tick
    picks = [rng.choice(classes) for _ in range(40)]
    dg = b"".join(frame(c, rng.randbytes(c.unpacker.size), i, 7, 1) for i, c in enumerate(picks))
    fast, ref = parse_unsigned_v2(dg), slow(dg)
    assert len(fast) == len(ref) == 40 and all(same(a, b) for a, b in zip(fast, ref))


def test_anything_unusual_goes_the_slow_counting_way():
    hb = M.MAVLink(None, srcSystem=1, srcComponent=1)
    good = hb.heartbeat_encode(2, 12, 0, 0, 3).pack(hb)
    assert parse_unsigned_v2(good) is not None
    bad_crc = good[:-1] + bytes(((good[-1] + 1) % 256,))
    v1 = M.MAVLink(None, srcSystem=1, srcComponent=1)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    for dg in (bad_crc, good[:-3], b"\x00" + good, good + b"\xfd\x09", bytes([0xFE]) + good[1:]):
        assert parse_unsigned_v2(dg) is None
    # unknown message id and a set incompat flag (signed)
    unknown = bytearray(good)
    unknown[7:10] = (0xFF, 0xFF, 0x00)
    assert parse_unsigned_v2(bytes(unknown)) is None
    signed = bytearray(good)
    signed[2] = 1
    assert parse_unsigned_v2(bytes(signed)) is None
    # through Codec: the slow path still counts what is dropped, as before
    c = Codec(255, 190)
    assert [m.get_type() for m in c.parse(good + bad_crc)] == ["HEARTBEAT"]
    assert c.stats.rx_bad == 1 and c.stats.rx_frames == 1
    assert len(c.parse(good)) == 1 and c.stats.rx_frames == 2


KEY = bytes(range(1, 33))


@pytest.mark.parametrize("seed", [0, 1])
def test_every_signed_message_of_the_dialect_decodes_as_pymavlink_does(seed):
    """Signed frames (the signature after the checksum) decode as pymavlink's parser without a
    key gives them, the signature kept in the frame bytes; a datagram of many too."""
    rng = random.Random(seed)
    signer = Signing(KEY)
    frames = []
    for cls in M.mavlink_map.values():
        payload = bytearray(rng.randbytes(cls.unpacker.size))
        if rng.random() < 0.5:
            payload[cls.unpacker.size // 2 :] = bytes(cls.unpacker.size - cls.unpacker.size // 2)
        f = signer.sign(frame(cls, bytes(payload), rng.randrange(256), rng.randrange(1, 256),
                              rng.randrange(256), compat=rng.choice((0, 1))), link_id=3)  # fmt: skip
        fast, ref = parse_signed_v2(f), slow(f)
        assert fast is not None and len(fast) == len(ref) == 1, cls.msgname
        assert same(fast[0], ref[0]) and len(fast[0].get_msgbuf()) == len(f), cls.msgname
        assert parse_unsigned_v2(f) is None
        frames.append(f)
    dg = b"".join(frames[:40])
    fast, ref = parse_signed_v2(dg), slow(dg)
    assert len(fast) == len(ref) == 40 and all(same(a, b) for a, b in zip(fast, ref))
    unsigned = frame(M.MAVLink_heartbeat_message, bytes(9), 0, 1, 1)
    assert parse_signed_v2(unsigned) is None and parse_signed_v2(dg + unsigned) is None
    assert parse_signed_v2(dg[:-1]) is None  # a signature cut short


def test_a_signing_codec_takes_signed_datagrams_the_fast_way_and_checks_each_frame():
    hb = M.MAVLink(None, srcSystem=1, srcComponent=1)
    sender = Codec(1, 1, signing=Signing(KEY))
    dg = b"".join(sender.pack(hb.heartbeat_encode(2, 12, 0, 0, 3)) for _ in range(3))
    c = Codec(255, 190, signing=Signing(KEY))
    assert [m.get_type() for m in c.parse(dg)] == ["HEARTBEAT"] * 3 and c.stats.rx_frames == 3
    assert c.parse(dg) == [] and c.stats.rx_rejected == 3  # replayed: each frame refused
    forger = Codec(1, 1, signing=Signing(bytes(32 * [7])))
    assert c.parse(forger.pack(hb.heartbeat_encode(2, 12, 0, 0, 3))) == []
    assert c.stats.rx_rejected == 4 and c.signing.stats["rejected_bad"] == 1


def test_with_signing_on_unsigned_frames_never_take_the_fast_path():
    c = Codec(255, 190, signing=Signing(key=bytes(range(1, 33))))
    hb = M.MAVLink(None, srcSystem=1, srcComponent=1)
    good = hb.sys_status_encode(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0).pack(hb)
    assert c.parse(good) == [] and c.stats.rx_rejected == 1  # unsigned SYS_STATUS: refused


@pytest.mark.parametrize("seed", [0, 1])
def test_signed_frames_decode_as_pymavlink_does_and_refused_ones_are_counted(seed):
    """A datagram of signed frames (every message of the dialect, a tick's worth at a time)
    gives the objects pymavlink's parser gives and passes our signing as the slow path does:
    the same frames again are replays, another key's frames are refused, a RADIO_STATUS
    unsigned is taken; a corrupt frame sends the datagram the slow, counting way."""
    key = bytes(range(1, 33))
    rng = random.Random(seed)
    tx = Codec(7, 1, signing=Signing(key), link_id=3)
    other = Codec(7, 1, signing=Signing(bytes(32 * [9])))
    rx = Codec(255, 190, signing=Signing(key))
    classes = list(M.mavlink_map.values())
    for k in range(0, len(classes), 8):
        frames = [tx.pack(random_message(cls, rng)) for cls in classes[k : k + 8]]
        dg = b"".join(frames)
        got = rx.parse(dg)
        ref = slow(dg)
        assert len(got) == len(ref) == len(frames)
        assert all(same(a, b) for a, b in zip(got, ref, strict=True))
        rejected = rx.stats.rx_rejected
        assert rx.parse(dg) == [] and rx.stats.rx_rejected == rejected + len(frames)  # replays
    forged = other.pack(M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    radio = Codec(7, 68).pack(M.MAVLink_radio_status_message(200, 190, 100, 20, 30, 0, 0))
    good = tx.pack(M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    rejected = rx.stats.rx_rejected
    assert [m.get_type() for m in rx.parse(forged + radio + good)] == ["RADIO_STATUS", "HEARTBEAT"]
    assert rx.stats.rx_rejected == rejected + 1
    late = tx.pack(M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3))
    bad = bytearray(tx.pack(M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)))
    bad[12] ^= 0xFF  # a payload byte: the CRC fails
    bad_before = rx.stats.rx_bad
    assert [m.get_type() for m in rx.parse(late + bytes(bad))] == ["HEARTBEAT"]
    assert rx.stats.rx_bad == bad_before + 1


def random_message(cls, rng: random.Random):
    """A message of `cls` from random wire bytes, decoded by pymavlink: every field in range."""
    payload = bytearray(rng.randbytes(cls.unpacker.size))
    if rng.random() < 0.5:  # payloads ending in zeros: the frame is truncated
        payload[cls.unpacker.size // 2 :] = bytes(cls.unpacker.size - cls.unpacker.size // 2)
    return slow(frame(cls, bytes(payload), 0, 1, 1))[0]


@pytest.mark.parametrize("seed", [0, 1])
def test_every_message_of_the_dialect_packs_as_pymavlink_does(seed):
    rng = random.Random(seed)
    for cls in M.mavlink_map.values():
        for _ in range(2):
            msg = random_message(cls, rng)
            seq, sysid, compid = rng.randrange(256), rng.randrange(1, 256), rng.randrange(256)
            ref_mav = M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
            ref_mav.seq = seq
            ref = bytes(msg.pack(ref_mav))
            ref_side = (bytes(msg._payload), vars(msg._header).copy(), bytes(msg._msgbuf), msg._crc)
            fast = pack_unsigned_v2(msg, seq, sysid, compid)
            assert fast == ref, cls.msgname
            side = (bytes(msg._payload), vars(msg._header).copy(), bytes(msg._msgbuf), msg._crc)
            assert side == ref_side, cls.msgname


def test_built_messages_pack_as_pymavlink_does():
    """Messages as the endpoint builds them (str text, lists and tuples for arrays, floats)."""
    mav = M.MAVLink(None, srcSystem=3, srcComponent=1)
    msgs = [
        mav.statustext_encode(6, b"Takeoff detected", 0, 0),
        mav.attitude_quaternion_encode(
            1000, 1.0, 0.0, 0.0, 0.0, 0.1, 0.2, 0.3, [0.0, 0.0, 0.0, 0.0]
        ),
        mav.battery_status_encode(0, 1, 1, 2500, [4200] * 10, 500, 100, 1000, 90),
        mav.param_value_encode(b"MPC_XY_VEL_MAX", 12.0, M.MAV_PARAM_TYPE_REAL32, 900, 3),
        mav.heartbeat_encode(2, 12, 129, 0x60000, 4),
        mav.local_position_ned_encode(123, float("nan"), -0.0, 1e30, 0.0, 0.0, 0.0),
    ]
    for m in msgs:
        ref_mav = M.MAVLink(None, srcSystem=3, srcComponent=1)
        ref_mav.seq = 200
        assert pack_unsigned_v2(m, 200, 3, 1) == bytes(m.pack(ref_mav)), m.get_type()


def test_a_message_out_of_range_fails_as_pymavlink_does():
    mav = M.MAVLink(None, srcSystem=3, srcComponent=1)
    m = mav.heartbeat_encode(2, 12, 300, 0, 4)  # base_mode is a uint8
    with pytest.raises(struct.error):
        m.pack(mav)
    with pytest.raises(struct.error):
        pack_unsigned_v2(m, 0, 3, 1)


def test_layouts_are_the_dialects_classes_only():
    """Layouts are made on first use, for the dialect's own classes: a subclass (or another
    dialect's class of the same id) is framed by pymavlink, as before; an unknown id has none."""

    class Custom(M.MAVLink_heartbeat_message):
        pass

    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    mine = Custom(2, 12, 0, 0, 3, 3)
    assert frame_unsigned_v2(mine, 0, 1, 1) is None
    assert Codec(1, 1).pack(mine) == bytes(Custom(2, 12, 0, 0, 3, 3).pack(mav))
    hb = M.MAVLink_heartbeat_message(2, 12, 0, 0, 3, 3)
    assert frame_unsigned_v2(hb, 0, 1, 1) == bytes(
        hb.pack(M.MAVLink(None, srcSystem=1, srcComponent=1))
    )
    assert (
        _LAYOUTS.known(0xFFFFFF) is None
        and _LAYOUTS.known(M.MAVLINK_MSG_ID_HEARTBEAT).cls is M.MAVLink_heartbeat_message
    )
    with pytest.raises(KeyError):
        _LAYOUTS[0xFFFFFF]
