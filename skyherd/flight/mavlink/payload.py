"""MAVLink payloads packed straight into bytes, without building pymavlink message objects.

`Payload` is one message ready for framing: its id and its full (untruncated) wire payload.
`packer(msg_id)` gives the function that packs a message's fields, passed in the declaration
order of pymavlink's `<name>_encode` (extension fields may be left out: their defaults), into
its wire payload: the precomputed struct, the declaration → wire order and the array fields,
byte for byte what pymavlink's generated `pack` writes (tests/flight/test_payload.py, over every
message of the dialect). Telemetry costs a struct pack a message instead of an object with a
dozen attributes and a second walk over them (issue 31).
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink


class Payload(NamedTuple):
    """One message as its id and its wire payload (trailing zeros not yet dropped)."""

    msg_id: int
    data: bytes


def _make_packer(msg_id: int) -> Callable[..., Payload]:
    cls = mavlink.mavlink_map[msg_id]
    encode = getattr(mavlink.MAVLink, f"{cls.msgname.lower()}_encode")
    params = list(inspect.signature(encode).parameters.values())[1:]  # without `self`
    if [p.name for p in params] != list(cls.fieldnames):
        raise ValueError(f"{cls.msgname}: encode arguments are not its fields")
    defaults = tuple(p.default for p in params)
    n_required = sum(p.default is inspect.Parameter.empty for p in params)
    n_all = len(params)
    pack = cls.unpacker.pack
    types = dict(zip(cls.fieldnames, cls.fieldtypes, strict=True))
    wire = [(cls.fieldnames.index(name), 0 if types[name] == "char" else n)
            for name, n in zip(cls.ordered_fieldnames, cls.array_lengths, strict=True)]  # fmt: skip

    def fill(args: tuple) -> tuple:
        n = len(args)
        if not n_required <= n <= n_all:
            raise TypeError(f"{cls.msgname} takes {n_required}..{n_all} fields, got {n}")
        return args + defaults[n:]

    # The wire-order argument list as source, arrays flattened: `a[3], a[0], a[8][0], ...`,
    # compiled once per message (as pymavlink's generated `pack` lists its fields).
    args = ", ".join(f"a[{i}]" if n == 0 else ", ".join(f"a[{i}][{k}]" for k in range(n))
                     for i, n in wire)  # fmt: skip
    code = (
        "def packer(*a):\n"
        "    if len(a) != n_all:\n"
        "        a = fill(a)\n"
        f"    return Payload(msg_id, pack({args}))\n"
    )
    scope = {"n_all": n_all, "fill": fill, "Payload": Payload, "msg_id": msg_id, "pack": pack}
    exec(compile(code, f"<packer {cls.msgname}>", "exec"), scope)  # noqa: S102 - our own source
    return scope["packer"]


_PACKERS: dict[int, Callable[..., Payload]] = {}


def packer(msg_id: int) -> Callable[..., Payload]:
    """The packer of message `msg_id` (made once, then shared). KeyError for an id the dialect
    does not know."""
    p = _PACKERS.get(msg_id)
    if p is None:
        p = _PACKERS[msg_id] = _make_packer(msg_id)
    return p
