"""runio/mac.py: a JSON record signed with one encoding (its canonical body, "mac" spliced in
last) carries the same MAC as before, verifies with the old re-encoding check and the old
writer's records verify with the new byte check; no payload is accepted that the re-encoding
check refuses (a second "mac", a misplaced one, whitespace, another key order, altered bytes).
Over Zenoh: tests/e2e/test_signing_zenoh.py, tests/e2e/test_signing_frames.py."""

from __future__ import annotations

import hashlib
import json
import math
import random

import numpy as np

from skyherd.runio.mac import payload_ok, record_mac, record_ok, sign_body, sign_record

KEY = bytes(range(32))
OTHER = bytes(range(1, 33))
UGV = {"id": 2, "seq": 17, "t_sim": 1.7000000000000002, "pos_ned": [12.5, -3.25, 0.0],
       "heading_rad": -0.3, "speed_mps": 1.5, "camouflaged": False}  # fmt: skip
DECISION = {"t": 3.0, "vehicle": "uav0", "pilot": "policy", "phi": [0.1, float("nan"), None],
            "proposed": {"vel_ned": [4.0, 0.0, 0.0], "mac": "nested, not the record's"},
            "certified": None, "verdict": "projected", "reason": "accel limit 4 m/s²"}  # fmt: skip
RECORDS = [UGV, DECISION, {"t_sim": 0.1}, {}, {"ü": "é", "a": [1, 2, {"b": True}]}]


def _old_mac(key: bytes, rec: dict) -> str:
    """The MAC as issue 27 defined it, written out: keyed BLAKE2b-256 of the sorted, compact
    JSON without "mac"."""
    body = json.dumps({k: v for k, v in rec.items() if k != "mac"}, sort_keys=True,
                      separators=(",", ":"))  # fmt: skip
    return hashlib.blake2b(body.encode(), key=key, digest_size=32).hexdigest()


def _old_payload(rec: dict, key: bytes) -> bytes:
    """What the writers sent before: the record in its order, default separators, "mac" last."""
    return json.dumps({**rec, "mac": _old_mac(key, rec)}).encode()


def _same(a: dict, b: dict) -> bool:
    return json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)  # NaN == NaN here


def _content(payload: bytes) -> dict:
    return {k: v for k, v in json.loads(payload).items() if k != "mac"}


def test_a_record_is_encoded_once_and_carries_the_mac_it_always_had_as_its_last_member():
    for rec in RECORDS:
        p = sign_record(rec, KEY)
        got = json.loads(p)
        assert list(got)[-1] == "mac" and got["mac"] == _old_mac(KEY, rec) == record_mac(KEY, rec)
        assert _same(_content(p), rec)
        body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
        member = b'"mac":"' + got["mac"].encode() + b'"}'
        assert p == (body[:-1] + b"," + member if rec else b"{" + member)  # the body + mac
    assert sign_record({"a": 1, "mac": "stale"}, KEY) == sign_record({"a": 1}, KEY)
    assert sign_record({"b": 1, "a": 2}, None) == b'{"b": 1, "a": 2}'  # unsigned: as before
    assert sign_record({"b": 1, "a": 2}, None, sort_keys=True) == b'{"a": 2, "b": 1}'


def test_new_and_old_signatures_verify_both_ways_and_only_with_their_key():
    for rec in RECORDS:
        new, old = sign_record(rec, KEY), _old_payload(rec, KEY)
        for p in (new, old):
            r = json.loads(p)
            assert record_ok(r, KEY) and payload_ok(p, r, KEY)  # old check, new check
            assert not record_ok(r, OTHER) and not payload_ok(p, r, OTHER)


def test_altered_forged_or_reshaped_payloads_are_refused_or_carry_the_signed_record():
    body = sign_record(UGV, KEY)[: -len(',"mac":"') - 64 - 2]  # the canonical body without "}"
    mac = record_mac(KEY, UGV)
    forged = {**UGV, "pos_ned": [500.0, 0.0, 0.0]}
    refused = [
        sign_record(UGV, KEY).replace(b"12.5", b"12.6"),  # an altered value, its mac kept
        sign_record(forged, OTHER),  # another key
        json.dumps({**forged, "mac": mac}).encode(),  # the real mac on other content
        body + b',"x":1,"mac":"' + mac.encode() + b'"}',  # a member added before the mac
        body + b',"id":5,"mac":"' + mac.encode() + b'"}',  # a member overridden after the body
        body + b',"mac":"' + mac.encode() + b'","mac":"' + 64 * b"0" + b'"}',  # 2nd mac wins
        body + b',"mac":"' + mac.upper().encode() + b'"}',  # the mac in capitals
        body + b"}",  # no mac at all
        b'{"mac":"' + mac.encode() + b'"}',  # the mac alone
    ]
    for p in refused:
        r = json.loads(p)
        assert not payload_ok(p, r, KEY) and not record_ok(r, KEY), p
    # reshaped, the same signed content: accepted, and what is read is what was signed
    accepted = [
        _old_payload(UGV, KEY),  # spaced, insertion order
        json.dumps({**UGV, "mac": mac}, sort_keys=True).encode(),  # sorted: mac not last
        b'{"mac":"' + mac.encode() + b'",' + body[1:] + b"}",  # mac first
        body + b',"mac":"' + 64 * b"0" + b'","mac":"' + mac.encode() + b'"}',  # 2nd mac, last
        b'{"id":5,' + body[1:] + b',"mac":"' + mac.encode() + b'"}',  # overridden by the body
        sign_record(UGV, KEY) + b"\n",  # whitespace after
        sign_record(UGV, KEY).replace(b",", b", "),  # whitespace inside
        json.dumps({**dict(reversed(UGV.items())), "mac": mac}, separators=(",", ":")).encode(),
    ]
    for p in accepted:
        r = json.loads(p)
        assert payload_ok(p, r, KEY) and record_ok(r, KEY) and _same(_content(p), UGV), p


def test_byte_check_agrees_with_the_re_encoding_check_on_every_mutated_payload():
    """Random byte edits of signed payloads: wherever the result still parses, the byte check
    accepts exactly what the re-encoding check accepts, and only the signed content."""
    rng = random.Random(0)
    alphabet = b'{}[],:" 0123456789.-eEtrufalsnmcNI\\'
    parsed = accepted = 0
    for rec in RECORDS:
        signed = sign_record(rec, KEY)
        for _ in range(3000):
            p = bytearray(signed)
            for _ in range(rng.randint(1, 3)):
                i = rng.randrange(len(p) + 1)
                op = rng.randrange(3)
                if op == 0 and i < len(p):
                    del p[i]
                elif op == 1:
                    p.insert(i, rng.choice(alphabet))
                elif i < len(p):
                    p[i] = rng.choice(alphabet)
            p = bytes(p)
            try:
                r = json.loads(p)
            except ValueError:
                continue
            if not isinstance(r, dict):
                continue
            parsed += 1
            ok = payload_ok(p, r, KEY)
            assert ok == record_ok(r, KEY), p
            if ok:
                accepted += 1
                assert _same(_content(p), rec), p
    assert parsed > 1000 and accepted > 0  # the edits reached both outcomes


def test_non_finite_numbers_sign_and_verify_as_before():
    rec = {"t": 1.0, "x": math.inf, "y": -math.inf, "z": math.nan}
    p = sign_record(rec, KEY)
    assert b"Infinity" in p and b"NaN" in p and payload_ok(p, json.loads(p), KEY)
    assert json.loads(p)["mac"] == _old_mac(KEY, rec)


def test_a_body_written_by_its_writer_signs_as_its_record_and_the_clock_as_before():
    from skyherd.world.scene import clock_payload

    for rec in RECORDS:
        body = json.dumps(rec, sort_keys=True, separators=(",", ":")).encode()
        assert sign_body(body, KEY) == sign_record(rec, KEY)
    rng = random.Random(6)
    times = [0.0, -0.0, 0.1, 99.9, 1e-7, 1e16, np.float64(2.5), 3, math.nan, math.inf, -math.inf]
    times += [rng.uniform(0, 1e4) for _ in range(2000)] + [k / 10 for k in range(2000)]
    for t in times:
        for key in (KEY, None):
            assert clock_payload(t, key) == sign_record({"t_sim": t}, key), (t, key)
