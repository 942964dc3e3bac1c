"""Cost of signing (issue 27): per MAVLink message and per camera frame, signed vs unsigned;
per signed JSON record, issue 31's one encoding vs issue 27's two.

    PYTHONPATH=. .venv/bin/python bench/bench_signing.py [--rounds 7] [--messages 20000] [--frames 200]

MAVLink: `Codec.pack` of a LOCAL_POSITION_NED (the stream the companion reads most), and pack
then `Codec.parse` on a receiving codec, without a key and with one (flight.mavlink.signing).
Frames: `encode_frame` of a camera-sized raw frame (build) and `decode_header` +
`decode_pixels` (check + decode), without a key and with the flight key (version 2: SHA-256 of
the pixels + keyed BLAKE2b over header and digest; perception/transport.py). CPU time
(time.process_time: what the machine's load does not change), A and B alternated round by
round in one run; the table gives the median per round and the ratio signed / unsigned.

JSON records (runio.mac; a UGV state as groundsim.transport sends it, `--messages` a round):
"sign" makes the payload, "check" parses it and checks its MAC. Issue 27's way, written out
here: the sorted compact JSON encoded to MAC it, then the record with "mac" encoded again;
checked by re-encoding the parsed record (`record_ok`). Issue 31's: `sign_record` (the
canonical body encoded once, "mac" spliced in) and `payload_ok` (the MAC over the received
bytes). Same rounds, alternated; the second table gives the ratio new / old.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import statistics
import time

import numpy as np

from skyherd.flight.mavlink.codec import Codec
from skyherd.flight.mavlink.signing import Signing
from skyherd.perception.camera import CameraParams
from skyherd.perception.transport import RAW, decode_header, decode_pixels, encode_frame
from skyherd.runio import markdown_table
from skyherd.runio.mac import payload_ok, record_ok, sign_record

UGV_STATE = {"id": 1, "seq": 517, "t_sim": 51.7, "pos_ned": [23.418734, -11.093256, 0.0],
             "heading_rad": 1.2593871, "speed_mps": 1.8461913, "camouflaged": False}  # fmt: skip


def _cpu(fn, n: int) -> float:
    """CPU seconds per call of fn over n calls."""
    t0 = time.process_time()
    for _ in range(n):
        fn()
    return (time.process_time() - t0) / n


def mavlink_cases(key: bytes | None):
    tx = Codec(1, 1, Signing(key) if key else None)
    rx = Codec(255, 190, Signing(key) if key else None)
    msg = tx.mav.local_position_ned_encode(1000, 1.0, 2.0, -20.0, 0.1, 0.2, 0.0)

    def pack():
        tx.pack(msg)

    def pack_parse():
        out = rx.parse(tx.pack(msg))
        assert len(out) == 1

    return pack, pack_parse


def frame_cases(key: bytes | None):
    cam = CameraParams()
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (cam.height_px, cam.width_px, 3), dtype=np.uint8)
    pos, quat = np.array([1.0, 2.0, -20.0]), np.array([1.0, 0.0, 0.0, 0.0])
    payload = encode_frame(1, 0.1, pos, quat, img, RAW, stream=7, key=key)

    def build():
        encode_frame(1, 0.1, pos, quat, img, RAW, stream=7, key=key)

    def check_decode():
        decode_pixels(decode_header(payload, key=key), payload)

    return build, check_decode, cam


def record_cases(key: bytes, new: bool):
    """(sign, check) of one UGV state: issue 31's way (new) or issue 27's (old)."""
    if new:
        payload = sign_record(UGV_STATE, key)
        return (lambda: sign_record(UGV_STATE, key),
                lambda: payload_ok(payload, json.loads(payload.decode()), key))  # fmt: skip

    def sign_old() -> bytes:
        body = json.dumps(UGV_STATE, sort_keys=True, separators=(",", ":")).encode()
        mac = hashlib.blake2b(body, key=key, digest_size=32).hexdigest()
        return json.dumps({**UGV_STATE, "mac": mac}).encode()

    payload = sign_old()
    return sign_old, lambda: record_ok(json.loads(payload.decode()), key)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    p.add_argument("--rounds", type=int, default=7, help="A/B rounds (default 7)")
    p.add_argument("--messages", type=int, default=20000, help="messages per round (default 20000)")
    p.add_argument("--frames", type=int, default=200, help="frames per round (default 200)")
    a = p.parse_args(argv)
    key = os.urandom(32)
    mav = {False: mavlink_cases(None), True: mavlink_cases(key)}
    frm = {False: frame_cases(None), True: frame_cases(key)}
    cam = frm[False][2]
    names = ["MAVLink pack", "MAVLink pack + parse", f"frame build ({cam.width_px}x{cam.height_px} raw)",
             "frame check + decode"]  # fmt: skip
    samples: dict[tuple[str, bool], list[float]] = {
        (n, s): [] for n in names for s in (False, True)
    }
    rec = {False: record_cases(key, False), True: record_cases(key, True)}
    rec_names = ["JSON record sign (UGV state)", "JSON record parse + check"]
    rec_samples: dict[tuple[str, bool], list[float]] = {
        (n, s): [] for n in rec_names for s in (False, True)
    }
    for r in range(a.rounds):
        for signed in (False, True) if r % 2 == 0 else (True, False):  # alternated A/B
            pack, pack_parse = mav[signed]
            build, check, _ = frm[signed]
            samples[(names[0], signed)].append(_cpu(pack, a.messages))
            samples[(names[1], signed)].append(_cpu(pack_parse, a.messages // 2))
            samples[(names[2], signed)].append(_cpu(build, a.frames))
            samples[(names[3], signed)].append(_cpu(check, a.frames))
            new = signed  # the record cases alternate with the same A/B order
            for name, fn in zip(rec_names, rec[new], strict=True):
                rec_samples[(name, new)].append(_cpu(fn, a.messages))
    rows = []
    for n in names:
        u = statistics.median(samples[(n, False)]) * 1e6
        s = statistics.median(samples[(n, True)]) * 1e6
        rows.append([n, f"{u:.2f}", f"{s:.2f}", f"{s / u:.2f}"])
    print(markdown_table(["per item", "unsigned [µs CPU]", "signed [µs CPU]", "ratio"], rows))
    print(
        f"(median of {a.rounds} alternated rounds; {a.messages} messages, {a.frames} frames a round)"
    )
    rows = []
    for n in rec_names:
        old = statistics.median(rec_samples[(n, False)]) * 1e6
        new = statistics.median(rec_samples[(n, True)]) * 1e6
        rows.append([n, f"{old:.2f}", f"{new:.2f}", f"{new / old:.2f}"])
    print()
    print(markdown_table(["per record", "issue 27: two encodings [µs CPU]",
                          "issue 31: one [µs CPU]", "ratio"], rows))  # fmt: skip
    print(f"(median of {a.rounds} alternated rounds; {a.messages} records a round)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
