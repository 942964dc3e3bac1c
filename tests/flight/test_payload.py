"""skyherd.flight.mavlink.payload: messages packed straight into bytes, against pymavlink's own
`<name>_encode` + `pack`, over the whole dialect, unsigned and signed."""

from __future__ import annotations

import random

import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink.codec import Codec, decode_payload
from skyherd.flight.mavlink.payload import Payload, packer
from skyherd.flight.mavlink.signing import Signing, now_units
from tests.flight.test_codec_fast import random_message

KEY = bytes(range(32))


def encode_args(m) -> list:
    """A decoded message's fields in `<name>_encode`'s order (char fields as their raw bytes)."""
    types = dict(zip(m.fieldnames, m.fieldtypes, strict=True))
    return [getattr(m, f"_{n}_raw") if types[n] == "char" else getattr(m, n) for n in m.fieldnames]


@pytest.mark.parametrize("seed", [0, 1])
def test_every_message_of_the_dialect_packs_as_pymavlink_encodes_it(seed):
    rng = random.Random(seed)
    for cls in M.mavlink_map.values():
        m = random_message(cls, rng)
        seq, sysid, compid = rng.randrange(256), rng.randrange(1, 256), rng.randrange(256)
        ref_mav = M.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        ref_mav.seq = seq
        ref = bytes(
            getattr(ref_mav, f"{cls.msgname.lower()}_encode")(*encode_args(m)).pack(ref_mav)
        )
        codec = Codec(sysid, compid)
        codec.tx.seq = seq
        p = packer(cls.id)(*encode_args(m))
        assert p.msg_id == cls.id
        assert codec.pack(p) == ref, cls.msgname
        assert repr(decode_payload(p).to_dict()) == repr(m.to_dict()), cls.msgname


def test_extension_fields_left_out_take_encodes_defaults_and_a_wrong_count_is_an_error():
    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    p = packer(M.MAVLINK_MSG_ID_BATTERY_STATUS)(0, 1, 1, 2500, [4200] * 10, 500, 100, 1000, 90)
    ref = mav.battery_status_encode(0, 1, 1, 2500, [4200] * 10, 500, 100, 1000, 90)
    assert Codec(1, 1).pack(p) == bytes(ref.pack(mav))  # both at sequence number 0
    assert decode_payload(p).voltages_ext == [0, 0, 0, 0]
    with pytest.raises(TypeError, match="BATTERY_STATUS takes 9..14 fields, got 3"):
        packer(M.MAVLINK_MSG_ID_BATTERY_STATUS)(0, 1, 1)
    with pytest.raises(KeyError):
        packer(999_999)


def test_a_signed_payload_frame_is_the_signed_frame_of_the_same_message():
    """Signing a Payload in one pass (flag set before the CRC) gives the bytes that signing the
    unsigned frame afterwards gives, at the same timestamp; pymavlink accepts it."""
    ts = now_units() + 10**9  # ahead of the wall clock: both signers use ts + 1
    ours, ref = Signing(KEY, ts), Signing(KEY, ts)
    codec, plain = Codec(3, 1, ours, link_id=2), Codec(3, 1)
    p = packer(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)(123, 1.5, -2.0, -10.0, 0.1, 0.0, 0.0)
    signed = codec.pack(p)
    assert signed == ref.sign(plain.pack(p), link_id=2)
    rx = M.MAVLink(None)
    rx.signing.secret_key, rx.signing.allow_unsigned_callback = KEY, None
    (msg,) = rx.parse_buffer(signed)
    assert msg.get_type() == "LOCAL_POSITION_NED" and msg.z == -10.0 and msg._signed
    assert isinstance(p, Payload)
