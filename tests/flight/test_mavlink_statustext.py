"""Long STATUSTEXT: chunked by the endpoint (MAVLink 2 id / chunk_seq), reassembled by
`hil.link.StatustextAssembler`, through pymavlink's own encoder and parser."""

from __future__ import annotations

import math

from mavlink_rig import Rig
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.mavlink.statustext import GAP, MAX_CHUNKS, TEXT_LEN, split_text
from skyherd.hil.link import StatustextAssembler

INSTANCE = 63  # mav helper: instances 60-64


def _wire(text: str, text_id: int = 9, system: int = 1, component: int = 1) -> list:
    """The STATUSTEXTs for `text` as a receiver decodes them from the wire."""
    tx, rx = M.MAVLink(None, system, component), M.MAVLink(None)
    out = []
    for tid, seq, chunk in split_text(text, text_id):
        frame = bytes(tx.statustext_encode(M.MAV_SEVERITY_WARNING, chunk, tid, seq).pack(tx))
        out += rx.parse_buffer(frame)
    return out


def test_split_sizes_and_the_terminating_chunk():
    assert [(i, s, len(c)) for i, s, c in split_text("x" * 50, 5)] == [(0, 0, 50)]
    assert [(i, s, len(c)) for i, s, c in split_text("x" * 51, 5)] == [(5, 0, 50), (5, 1, 1)]
    # A multiple of 50: an empty last chunk carries the NUL that ends the text.
    assert [len(c) for _, _, c in split_text("x" * 100, 5)] == [50, 50, 0]
    long = split_text("y" * 5000, 5)
    assert len(long) == MAX_CHUNKS and long[-1][2].endswith(b"...")


def test_reassembly_through_pymavlink_roundtrip():
    asm = StatustextAssembler()
    for n in (1, 49, 50, 51, 99, 100, 101, 333):
        text = "".join(chr(ord("a") + i % 26) for i in range(n))
        msgs = _wire(text, text_id=n)
        done = [asm.feed(m) for m in msgs]
        assert done[:-1] == [None] * (len(msgs) - 1) and done[-1] == text, n
    assert asm._partial == {}


def test_interleaved_senders_missing_chunk_and_bounded_partials():
    asm = StatustextAssembler(max_partial=4)
    a, b = "A" * 120, "B" * 75
    ma, mb = _wire(a, 1, system=1), _wire(b, 1, system=2)  # same id, other sender
    out = [asm.feed(m) for pair in zip(ma, mb) for m in pair] + [asm.feed(m) for m in ma[2:]]
    assert sorted(t for t in out if t) == [a, b]
    c = _wire("C" * 120, 2)
    assert asm.feed(c[0]) is None and asm.feed(c[2]) == "C" * 50 + GAP + "C" * 20
    for i in range(10):  # texts that never finish cost a bounded amount
        asm.feed(_wire("D" * 80, 100 + i)[0])
    assert len(asm._partial) == 4 and asm.dropped == 6


def test_endpoint_sends_a_long_refusal_in_chunks_that_reassemble():
    with Rig(INSTANCE) as rig:
        rig.client.recv()
        rig.client.send(rig.client.mav.command_long_encode(
            rig.sys, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, math.nan, math.nan, 10.0), rig.api)  # fmt: skip
        rig.step()
        chunks = [m for m in rig.client.recv() if m.get_type() == "STATUSTEXT"]
        assert len(chunks) >= 2 and len({m.id for m in chunks}) == 1 and chunks[0].id != 0
        assert [m.chunk_seq for m in chunks] == list(range(len(chunks)))
        assert all(len(m.text) == TEXT_LEN for m in chunks[:-1])
        asm = StatustextAssembler()
        (text,) = [t for t in map(asm.feed, chunks) if t]
        assert text.startswith("cmd 22: takeoff altitude") and text.endswith("out of range")
        assert len(text) > TEXT_LEN
