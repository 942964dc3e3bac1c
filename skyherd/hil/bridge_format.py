"""The JSON bridge's reply formatted in compiled code, byte for byte what Python's `%` gives.

`format_reply(t, out, template, tx)` writes one reply line into the preallocated byte array
`tx` and returns its length: the template is the reply's format string as bytes with each
`%.9f` replaced by byte 1 and each `%.9g` by byte 2 (`make_template`); the first
placeholder takes `t`, the next ones `out[0]`, `out[1]`, … in order.

Both conversions are correctly rounded, as CPython's (and C's) are: the value is scaled
by a power of ten in double-double arithmetic (Dekker's exact product; the power's
low part from exact rational arithmetic at import), and the 9 (or, for `%.9f`, all the)
digits are rounded from that. When the scaled value lies so close to a rounding boundary
that its error bound (about 2⁻¹⁰⁰ of it) could decide the rounding, and it is not an exact
tie of an exact product (ties go to even, as in C), the kernel returns -1 and the caller
formats with Python; so do values that are not finite or lie outside 1e-30 … 1e30
(`%.9f`: 0 … 9e6). The output is therefore always exactly `template % values`
(tests/hil/test_bridge_format.py checks it against Python on random and edge values).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
from numba import njit

from skyherd.hil.bridge_physics import quad_step_pwm

SPEC_F9 = 1  # %.9f in a template
SPEC_G9 = 2  # %.9g in a template
K_MIN, K_MAX = -40, 40  # powers of ten kept as double-double


def _pow10_table() -> tuple[np.ndarray, np.ndarray]:
    """10**k for k in K_MIN..K_MAX as hi + lo doubles (hi the nearest double, lo the nearest
    double to the rest: exact to about 2⁻¹⁰⁶ relative)."""
    hi = np.empty(K_MAX - K_MIN + 1)
    lo = np.empty(K_MAX - K_MIN + 1)
    for i, k in enumerate(range(K_MIN, K_MAX + 1)):
        exact = Fraction(10) ** k
        h = float(exact)
        hi[i] = h
        lo[i] = float(exact - Fraction(h))
    return hi, lo


POW10_HI, POW10_LO = _pow10_table()


def make_template(fmt: str) -> np.ndarray:
    """A `%`-format string of literal text, `%.9f` and `%.9g` only, as the kernel's template."""
    if "\x01" in fmt or "\x02" in fmt:
        raise ValueError("the format may not contain bytes 1 or 2")
    body = fmt.replace("%.9f", "\x01").replace("%.9g", "\x02")
    if "%" in body:
        raise ValueError(f"only %.9f and %.9g are compiled: {fmt!r}")
    return np.frombuffer(body.encode(), dtype=np.uint8).copy()


@njit(cache=True)
def _split(a):
    c = 134217729.0 * a  # 2**27 + 1: Veltkamp's split into two 26-bit halves
    hi = c - (c - a)
    return hi, a - hi


@njit(cache=True)
def _scaled(v, k):
    """v * 10**k as (hi, lo) with |error| <= ~2**-100 |v 10**k|, and whether it is exact."""
    ph = POW10_HI[k - K_MIN]
    pl = POW10_LO[k - K_MIN]
    p = v * ph
    ah, al = _split(v)
    bh, bl = _split(ph)
    err = ((ah * bh - p) + ah * bl + al * bh) + al * bl  # v * ph - p, exactly
    return p, err + v * pl, pl == 0.0


@njit(cache=True)
def _round(hi, lo, exact):
    """The integer nearest hi + lo (ties to even), or -1 when the error bound could decide."""
    n = np.floor(hi)
    d = (hi - n - 0.5) + lo  # hi - n and its difference to 0.5 are exact (hi >= 1)
    if d > 1e-12:
        return n + 1
    if d < -1e-12:
        return n
    if not exact or d != 0.0:
        return -1.0
    return n if n % 2.0 == 0.0 else n + 1  # an exact tie: to even


@njit(cache=True)
def _digits(n, count, tx, pos):
    """The `count` decimal digits of the integer n (zero-padded) at tx[pos:]."""
    m = np.int64(n)
    for i in range(count - 1, -1, -1):
        tx[pos + i] = 48 + m % 10
        m //= 10
    return pos + count


@njit(cache=True)
def fmt_f9(v, tx, pos):
    """'%.9f' % v at tx[pos:]; the new end, or -1 (see the module's docstring)."""
    if not (0.0 <= v < 9e6):
        return -1
    hi, lo, exact = _scaled(v, 9)
    if v == 0.0:
        n = 0.0
    elif hi < 1.0:  # _round needs hi >= 1: below 1e-9, Python's
        return -1
    else:
        n = _round(hi, lo, exact)
        if n < 0.0:
            return -1
    whole = np.int64(n) // 1_000_000_000
    frac = np.int64(n) % 1_000_000_000
    w = 1
    x = whole
    while x >= 10:
        x //= 10
        w += 1
    pos = _digits(whole, w, tx, pos)
    tx[pos] = 46  # '.'
    return _digits(frac, 9, tx, pos + 1)


@njit(cache=True)
def fmt_g9(v, tx, pos):
    """'%.9g' % v at tx[pos:]; the new end, or -1 (see the module's docstring)."""
    if v == 0.0:
        if math.copysign(1.0, v) < 0.0:
            tx[pos] = 45  # '-0'
            pos += 1
        tx[pos] = 48
        return pos + 1
    a = abs(v)
    if not (1e-30 <= a <= 1e30):
        return -1
    e = int(math.floor(math.log10(a)))
    hi, lo, exact = _scaled(a, 8 - e)
    if hi < 1e8:  # log10 one too high
        e -= 1
        hi, lo, exact = _scaled(a, 8 - e)
    elif hi >= 1e9:  # one too low
        e += 1
        hi, lo, exact = _scaled(a, 8 - e)
    if not (1e8 <= hi < 1e9):
        return -1
    n = _round(hi, lo, exact)
    if n < 0.0:
        return -1
    if n >= 1e9:  # rounded up to the next power of ten
        n = 1e8
        e += 1
    if v < 0.0:
        tx[pos] = 45
        pos += 1
    scratch = tx.size - 9  # the 9 digits, written at the end of tx first
    _digits(np.int64(n), 9, tx, scratch)
    last = 8  # the last significant digit kept (%g strips trailing zeros)
    while last > 0 and tx[scratch + last] == 48:
        last -= 1
    if -4 <= e < 9:  # fixed notation
        if e >= 0:
            for i in range(e + 1):
                tx[pos] = tx[scratch + i]
                pos += 1
            if last > e:
                tx[pos] = 46
                pos += 1
                for i in range(e + 1, last + 1):
                    tx[pos] = tx[scratch + i]
                    pos += 1
        else:
            tx[pos] = 48
            tx[pos + 1] = 46
            pos += 2
            for _ in range(-e - 1):
                tx[pos] = 48
                pos += 1
            for i in range(last + 1):
                tx[pos] = tx[scratch + i]
                pos += 1
        return pos
    tx[pos] = tx[scratch]  # exponent notation: d[.ddd]e±XX
    pos += 1
    if last > 0:
        tx[pos] = 46
        pos += 1
        for i in range(1, last + 1):
            tx[pos] = tx[scratch + i]
            pos += 1
    tx[pos] = 101  # 'e'
    tx[pos + 1] = 45 if e < 0 else 43
    pos += 2
    x = abs(e)
    return _digits(x, 3 if x >= 100 else 2, tx, pos)


@njit(cache=True)
def format_reply(t, out, template, tx):
    """template % (t, *out) into tx (see the module's docstring): its length, or -1."""
    pos = 0
    k = 0
    for i in range(template.size):
        c = template[i]
        if c == SPEC_F9 or c == SPEC_G9:
            v = t if k == 0 else out[k - 1]
            k += 1
            pos = fmt_f9(v, tx, pos) if c == SPEC_F9 else fmt_g9(v, tx, pos)
            if pos < 0:
                return -1
        else:
            tx[pos] = c
            pos += 1
    return pos


def compiled_for(kernel, args: tuple):
    """`kernel` compiled (or loaded from numba's cache) for exactly the types of `args`, as a
    function called without numba's per-call dispatch on the argument types (~0.6 µs of the
    13 arguments of `quad_frame`, a tenth of the bridge's frame). Only for arguments whose
    types never change (the bridge's own arrays and floats)."""
    from numba import typeof

    return kernel.compile(tuple(typeof(a) for a in args))


@njit(cache=True)
def quad_frame(rx, pwm_min, pwm_max, x, aux, p, u, dt, max_h, out, t, template, tx):
    """One JSON frame of the quadrotor in one call: motors from the servo packet in rx, the
    step by dt (`bridge_physics.quad_step_pwm`), then the reply for time t into tx: its
    length, or -1 when Python must format it (from `out`)."""
    quad_step_pwm(rx, pwm_min, pwm_max, x, aux, p, u, dt, max_h, out)
    return format_reply(t, out, template, tx)
