"""The JSON bridge's compiled reply (hil/bridge_format.py) is byte for byte Python's `%`."""

from __future__ import annotations

import math
import random
import struct

import numpy as np
import pytest

from skyherd.hil.ardupilot_json import _REPLY_B, REPLY_FMT, ArduPilotJsonBridge
from skyherd.hil.bridge_format import fmt_f9, fmt_g9, format_reply, make_template

TX = np.zeros(512, dtype=np.uint8)
G9, F9 = "%.9g", "%.9f"  # what the bridge's format string holds (Python's `%`)
EDGES = [0.0, -0.0, 1.0, -1.0, 9.80665, -9.80665, 1e-5, 1e-4, 9.99999999e-5, 0.5, 1.5, 2.5]
EDGES += [123456789.0, 999999999.5, 999999998.5, 1e9, 1e8, 99999999.95, 100000000.5, 1e-30]
EDGES += [1e30, 12345678.25, 0.1, 1 / 3, 2 / 3, 1e22, 1e23, 5e-324, 1e300, math.inf, math.nan]


def _g(v: float) -> str | None:
    n = fmt_g9(v, TX, 0)
    return None if n < 0 else TX[:n].tobytes().decode()


def _values(n: int, seed: int = 1) -> list[float]:
    rng = random.Random(seed)
    out = []
    for _ in range(n):
        k = rng.random()
        if k < 0.3:
            out.append(rng.uniform(-1, 1) * 10 ** rng.randint(-30, 29))
        elif k < 0.45:
            out.append(struct.unpack("<d", struct.pack("<Q", rng.getrandbits(64)))[0])
        elif k < 0.65:
            out.append(round(rng.uniform(-1e4, 1e4), rng.randint(0, 12)))  # short decimals
        elif k < 0.85:
            out.append(rng.randint(-(10**10), 10**10) / 2 ** rng.randint(0, 40))  # exact ties
        else:
            out.append(float(np.float32(rng.uniform(-100, 100))))
    return out


def test_g9_is_pythons_or_declines():
    declined = 0
    in_range = 0
    for v in EDGES + _values(100_000):
        got = _g(v)
        ok_range = v == 0 or 1e-30 <= abs(v) <= 1e30
        in_range += ok_range
        if got is None:
            declined += ok_range
            continue
        assert got == G9 % v, repr(v)
    assert declined < 1e-3 * in_range  # Python's own formatting is the rare exception


def test_f9_is_pythons_for_timestamps():
    t, ts = 0.0, [0.0, 1e-9, 5e-10, 1.5e-9, 2.5e-9, 1.0000000005]
    for rate in (400, 399, 1200, 50):
        for _ in range(20_000):
            t += 1.0 / rate
            ts.append(t)
    ts += [random.Random(2).uniform(0, 9e6) for _ in range(20_000)]
    declined = 0
    for v in ts:
        n = fmt_f9(v, TX, 0)
        if n < 0:
            declined += 1
            continue
        assert TX[:n].tobytes().decode() == F9 % v, repr(v)
    assert declined <= 3


def test_template_only_takes_what_it_compiles():
    assert make_template("a%.9fb%.9g").tolist() == [97, 1, 98, 2]
    with pytest.raises(ValueError):
        make_template("%.6f")


def test_bridge_replies_are_pythons_formatting_frame_by_frame():
    """A bridge flown through climb, yaw and descent answers each frame with exactly
    `REPLY_FMT % (t, *out)` (what it sent before the reply was compiled)."""
    b = ArduPilotJsonBridge(instance=86)
    tm = make_template(REPLY_FMT)
    hdr = struct.Struct("<HHI16H")
    for fc in range(3000):
        pwm = [1000 + (fc * 7 + 130 * i) % 900 for i in range(4)]
        b._rx[:40] = np.frombuffer(hdr.pack(18458, 400 - fc % 3, fc, *pwm, *[0] * 12), np.uint8)
        stepped, reply = b.handle(40, 0.0)
        assert stepped
        expect = _REPLY_B % (b.t, *b.body.out.tolist())
        assert reply == expect
        n = format_reply(b.t, b.body.out, tm, TX)
        assert n < 0 or TX[:n].tobytes() == expect
