"""MAVLink 2 framing with pymavlink's `ardupilotmega` dialect (which includes `common`).

The dialect is imported explicitly (never chosen by an environment variable). One `Codec`
per link: it numbers outgoing frames and parses each UDP datagram on its own, so a truncated
or corrupt datagram cannot swallow the next one. MAVLink 1 frames are parsed too. With a
`Signing` whose key is set, outgoing frames are signed and incoming ones verified
(flight.mavlink.signing); rejected frames are counted in `rx_rejected`.
"""

from __future__ import annotations

from dataclasses import dataclass
from operator import attrgetter, itemgetter

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.mavlink.payload import Payload
from skyherd.flight.mavlink.signing import IFLAG_SIGNED, SIGNATURE_LEN, Signing, is_signed
from skyherd.flight.mavlink.wire import CRC, HDR_V2, STX_V2, X25

MAVLinkMessage = mavlink.MAVLink_message
_new_object = object.__new__


class _Layout:
    """How pymavlink's `decode` turns one message id's payload into its message object, and
    its generated `pack` the object into a payload, precomputed: the struct, the wire ↔
    declaration field order, the array groups, the char fields (NUL-stripped on decode, their
    raw bytes on encode)."""

    def __init__(self, cls):
        self.cls = cls
        self.msg_id = cls.id
        self.size = cls.unpacker.size
        self.unpack = cls.unpacker.unpack
        self.unpack_from = cls.unpacker.unpack_from
        self.zeros = bytes(self.size)  # a truncated payload's dropped trailing zeros, and more
        self.pack_payload = cls.unpacker.pack
        self.extra = bytes((cls.crc_extra,))
        orders, lengths = cls.orders, cls.lengths
        self.flat = sum(lengths) == len(lengths)
        if self.flat:
            self.order = itemgetter(*orders) if len(orders) > 1 else (lambda t: (t[orders[0]],))
        else:  # (start, length) of each field in the unpacked tuple, in declaration order
            starts = [sum(lengths[:o]) for o in range(len(lengths))]
            self.groups = [(starts[o], lengths[o]) for o in orders]
        self.chars = [i for i, t in enumerate(cls.fieldtypes) if t == "char"]  # declaration order
        # unpacked payload → field values: for a message of plain numbers, one C call
        self.fields = self.order if self.flat and not self.chars else self._fields
        self.wire_values = _wire_getter(cls)
        self._attributes(cls)

    def _attributes(self, cls) -> None:
        """What pymavlink's generated `__init__` leaves on an object of the class, in its order:
        the base's bookkeeping, then each field (a char field as its raw bytes `_NAME_raw`, then
        NAME, those bytes up to the first NUL as text). `_decode` fills a copy of `template`."""
        names = cls.fieldnames
        raw = {names[i]: f"_{names[i]}_raw" for i in self.chars}
        self.keys = tuple(raw.get(name, name) for name in names)  # where each field goes
        self.texts = tuple(raw.items())  # (NAME, _NAME_raw)
        # _signed stays False: pymavlink's parser holds no key (signatures are ours to check)
        self.template = {
            "_header": None, "_payload": None, "_msgbuf": None, "_crc": None,
            "_fieldnames": names, "_type": cls.msgname, "_signed": False, "_link_id": None,
            "_instances": None, "_instance_field": cls.instance_field,
            "_instance_offset": cls.instance_offset,
        }  # fmt: skip
        for name in names:
            if name in raw:
                self.template[raw[name]] = None
            self.template[name] = None

    def _fields(self, t: tuple) -> list:
        """The field values of an unpacked payload `t`, in declaration order, char fields with
        their trailing NULs stripped: the arguments of the class's `__init__`."""
        if self.flat:
            fields = list(self.order(t))
        else:
            fields = [
                t[a] if n == 1 or isinstance(t[a], bytes) else list(t[a : a + n])
                for a, n in self.groups
            ]
        for i in self.chars:
            fields[i] = fields[i].rstrip(b"\x00")
        return fields

    def message(self, payload: bytes):
        return self.cls(*self.fields(self.unpack(payload)))


def _wire_getter(cls):
    """msg → its field values in wire order, arrays flattened, char fields as their raw bytes:
    the arguments of the struct pack in pymavlink's generated `pack`."""
    types = dict(zip(cls.fieldnames, cls.fieldtypes))
    specs = [(f"_{name}_raw" if types[name] == "char" else name, 0 if types[name] == "char" else n)
             for name, n in zip(cls.ordered_fieldnames, cls.array_lengths)]  # fmt: skip
    if all(n == 0 for _, n in specs):
        get = attrgetter(*(name for name, _ in specs))
        return get if len(specs) > 1 else (lambda m: (get(m),))

    def values(m) -> list:
        out = []
        for name, n in specs:
            v = getattr(m, name)
            if n:
                out.extend([v[i] for i in range(n)])
            else:
                out.append(v)
        return out

    return values


class _Layouts(dict):
    """Message id → its `_Layout`, each made on first use: a flight speaks a dozen of the
    dialect's 300 messages, and making them all cost every process importing this ~3 ms.
    `layouts[msg_id]` raises KeyError for an id the dialect does not know, `known` gives None."""

    def __missing__(self, msg_id: int) -> _Layout:
        lay = self[msg_id] = _Layout(mavlink.mavlink_map[msg_id])
        _BY_CLASS[lay.cls] = lay
        return lay

    def known(self, msg_id: int) -> _Layout | None:
        return self[msg_id] if msg_id in mavlink.mavlink_map else None


_LAYOUTS = _Layouts()
_BY_CLASS: dict[type, _Layout] = {}  # the dialect's message classes whose layout was made


def _layout_of(cls: type) -> _Layout | None:
    """The layout of one of the dialect's message classes; None for any other class (pymavlink
    frames it), a subclass or another dialect's class of the same id included."""
    lay = _BY_CLASS.get(cls)
    if lay is None and mavlink.mavlink_map.get(getattr(cls, "id", None)) is cls:
        lay = _LAYOUTS[cls.id]
    return lay


def decode_payload(p: Payload) -> MAVLinkMessage:
    """The pymavlink message a `Payload` stands for (tools and tests read its fields)."""
    return _LAYOUTS[p.msg_id].message(p.data)


def frame_unsigned_v2(msg: MAVLinkMessage, seq: int, src_sys: int, src_comp: int) -> bytes | None:
    """One unsigned MAVLink 2 frame of `msg`, byte for byte what pymavlink's `msg.pack` gives
    (trailing-zero truncation, CRC_EXTRA), leaving `msg` as it was; None for a message class
    the dialect does not know (the caller packs it with pymavlink).

    It costs a third of pymavlink's `_pack`, which builds a header object and an X.25
    accumulator in Python per frame: with K vehicles' streams that was a simulator's largest
    cost after the physics."""
    lay = _layout_of(type(msg))
    if lay is None:
        return None
    return _frame_of(lay, lay.pack_payload(*lay.wire_values(msg)), seq, src_sys, src_comp)


def _frame_of(lay: _Layout, payload: bytes, seq: int, src_sys: int, src_comp: int,
              incompat: int = 0) -> bytes:  # fmt: skip
    """Header, the payload without its trailing zeros (MAVLink 2 keeps one byte), CRC."""
    body = payload.rstrip(b"\x00") or payload[:1]
    msg_id = lay.msg_id
    frame = HDR_V2.pack(
        STX_V2, len(body), incompat, 0, seq, src_sys, src_comp, msg_id & 0xFFFF, msg_id >> 16
    )
    frame += body
    return frame + CRC.pack(X25(lay.extra, X25(frame[1:])))


def pack_unsigned_v2(msg: MAVLinkMessage, seq: int, src_sys: int, src_comp: int) -> bytes | None:
    """`frame_unsigned_v2`, with pymavlink's bookkeeping on `msg` as `msg.pack` leaves it
    (header, payload, crc, msgbuf); the tests compare both over every message of the dialect."""
    frame = frame_unsigned_v2(msg, seq, src_sys, src_comp)
    if frame is None:
        return None
    plen = frame[1]
    msg._payload = frame[10:-2]
    msg_id = frame[7] | frame[8] << 8 | frame[9] << 16  # (a field may be named `id`)
    msg._header = mavlink.MAVLink_header(msg_id, 0, 0, plen, seq, src_sys, src_comp)
    msg._msgbuf = bytearray(frame)
    msg._crc = frame[-2] | frame[-1] << 8
    return frame


def parse_unsigned_v2(datagram: bytes) -> list[MAVLinkMessage] | None:
    """Every frame of a datagram made only of whole, unsigned MAVLink 2 frames of known ids
    with good checksums, decoded to exactly what pymavlink's parser gives (the tests compare
    them over every message of the dialect); None for anything else (MAVLink 1, signed,
    unknown, corrupt or truncated), which the caller then parses the slow, counting way.

    A datagram of telemetry decoded here costs a few µs a frame; pymavlink's byte-wise
    parser, tens: with K vehicles' streams that parser was the companion's largest cost."""
    spans = _scan_v2(datagram, signed=False)
    return None if spans is None else [_decode(datagram[i:end], lay) for i, end, _, lay in spans]


def parse_signed_v2(datagram: bytes) -> list[MAVLinkMessage] | None:
    """`parse_unsigned_v2` for a datagram made only of signed frames (the 13-byte signature after
    the checksum), decoded as pymavlink's parser without a key gives them (the signature kept in
    `get_msgbuf()`); None for anything else. Signatures are not checked here (`Codec.parse`
    verifies each frame's bytes before it decodes it)."""
    spans = _scan_v2(datagram, signed=True)
    if spans is None or any(sig == 0 for _, _, sig, _ in spans):
        return None
    return [_decode(datagram[i:end], lay) for i, end, _, lay in spans]


_Span = tuple[int, int, int, _Layout]  # start, end (signature included), signature length, layout


def _scan_v2(datagram: bytes, signed: bool) -> list[_Span] | None:
    """The frames of a datagram made only of whole MAVLink 2 frames of known ids with good
    checksums (`signed`: frames with the signature flag too, their 13 bytes not checked here);
    None for anything else. Looks, changes nothing: a caller that gets None parses it all
    again the slow way, so nothing may have been verified (a replay window moved) before."""
    out = []
    i, n = 0, len(datagram)
    while i < n:
        if n - i < 12 or datagram[i] != STX_V2:
            return None  # not MAVLink 2
        flags = datagram[i + 2]
        sig = SIGNATURE_LEN if signed and flags == IFLAG_SIGNED else 0
        if flags and not sig:
            return None  # signed where not expected, or an unknown incompat flag: slow path
        end = i + 12 + datagram[i + 1]
        if end + sig > n:
            return None
        msg_id = datagram[i + 7] | datagram[i + 8] << 8 | datagram[i + 9] << 16
        lay = _LAYOUTS.get(msg_id) or _LAYOUTS.known(msg_id)  # (made on first use)
        if lay is None:
            return None
        crc = datagram[end - 2] | datagram[end - 1] << 8
        if X25(lay.extra, X25(datagram[i + 1 : end - 2])) != crc:
            return None
        out.append((i, end + sig, sig, lay))
        i = end + sig
    return out


def _decode(frame: bytes, lay: _Layout) -> MAVLinkMessage:
    """One scanned frame as pymavlink's parser (without a key of its own) decodes it, attribute
    for attribute, without the class's `__init__` chain: a copy of the layout's `template`
    with the frame's bookkeeping and the payload's fields filled in."""
    _, plen, incompat, compat, seq, src_sys, src_comp, _, _ = HDR_V2.unpack_from(frame)
    crc_at = 10 + plen
    msgbuf = bytearray(frame)
    attrs = lay.template.copy()
    attrs["_header"] = mavlink.MAVLink_header(
        lay.msg_id, incompat, compat, plen, seq, src_sys, src_comp
    )
    attrs["_payload"] = msgbuf[6:crc_at]  # as pymavlink's decode sets it
    attrs["_msgbuf"] = msgbuf
    attrs["_crc"] = frame[crc_at] | frame[crc_at + 1] << 8
    # the payload, then zeros: a truncated one gets its dropped trailing zeros back, a longer one
    # (extensions this dialect does not know) is read up to the size we know
    t = lay.unpack_from(frame[10:crc_at] + lay.zeros)
    attrs.update(zip(lay.keys, lay.fields(t)))
    for name, raw in lay.texts:
        attrs[name] = attrs[raw].split(b"\x00", 1)[0].decode("ascii", errors="replace")
    m = _new_object(lay.cls)
    m.__dict__ = attrs
    return m


@dataclass
class CodecStats:
    """Counters for one link: frames decoded, bytes or frames dropped as malformed."""

    rx_frames: int = 0
    rx_bad: int = 0
    rx_rejected: int = 0  # valid frames refused by signing (unsigned, bad signature, replay)
    tx_frames: int = 0
    tx_bytes: int = 0


class Codec:
    """Encode our messages as (system, component) and decode datagrams from the link."""

    def __init__(
        self, system_id: int, component_id: int, signing: Signing | None = None, link_id: int = 0
    ):
        self.signing = signing
        self.link_id = link_id  # this link's id in the signatures it sends
        self.tx = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.stats = CodecStats()

    @property
    def mav(self) -> mavlink.MAVLink:
        """The encoder: `codec.mav.heartbeat_encode(...)` builds a message."""
        return self.tx

    def pack(self, msg: MAVLinkMessage | Payload) -> bytes:
        """Frame one message (MAVLink 2) with the next sequence number: a pymavlink message, or
        a `Payload` packed straight into bytes (flight.mavlink.payload: the telemetry)."""
        if type(msg) is Payload:
            lay = _LAYOUTS[msg.msg_id]
            payload = msg.data
        else:
            lay = _layout_of(type(msg))
            if lay is None:  # a class the dialect does not know: pymavlink frames it
                return self._pymavlink_pack(msg)
            payload = lay.pack_payload(*lay.wire_values(msg))
        return self._frames([(lay, payload)])[0]

    def pack_payloads(self, payloads: list[Payload]) -> list[bytes]:
        """`pack` of each payload in order (a stream instant's telemetry), signed as one batch."""
        return self._frames([(_LAYOUTS[p.msg_id], p.data) for p in payloads])

    def _frames(self, items: list[tuple[_Layout, bytes]]) -> list[bytes]:
        """The frames of (layout, payload) pairs, numbered in order, and with a key signed (the
        incompat flag is set before the CRC is computed, so it is computed once)."""
        sg, tx = self.signing, self.tx
        signed = sg is not None and sg.key is not None
        incompat = IFLAG_SIGNED if signed else 0
        seq, src_sys, src_comp = tx.seq, tx.srcSystem, tx.srcComponent
        frames = []
        for lay, payload in items:
            frames.append(_frame_of(lay, payload, seq, src_sys, src_comp, incompat))
            seq = (seq + 1) % 256
        if signed:
            frames = sg.sign_frames(frames, self.link_id)
        tx.seq = seq
        stats = self.stats
        stats.tx_frames += len(frames)
        stats.tx_bytes += sum(map(len, frames))
        return frames

    def _pymavlink_pack(self, msg: MAVLinkMessage) -> bytes:
        buf = bytes(msg.pack(self.tx))
        if self.signing is not None and self.signing.key is not None:
            buf = self.signing.sign(buf, self.link_id)
        return self._count(buf)

    def _count(self, buf: bytes) -> bytes:
        self.tx.seq = (self.tx.seq + 1) % 256
        self.stats.tx_frames += 1
        self.stats.tx_bytes += len(buf)
        return buf

    def parse(self, datagram: bytes) -> list[MAVLinkMessage]:
        """Decode every valid frame in one datagram; malformed bytes are counted and dropped."""
        datagram = bytes(datagram)
        sg = self.signing
        if sg is None or sg.key is None:
            fast = parse_unsigned_v2(datagram)
            if fast is not None:
                self.stats.rx_frames += len(fast)
                return fast
        else:  # signed frames checked on the bytes: a refused one is never decoded
            spans = _scan_v2(datagram, signed=True)
            if spans is not None:
                out = []
                for i, end, _, lay in spans:
                    frame = datagram[i:end]
                    if sg.verify(frame, lay.msg_id, frame[5], frame[6]) is None:
                        out.append(_decode(frame, lay))
                    else:
                        self.stats.rx_rejected += 1
                self.stats.rx_frames += len(out)
                return out
        rx = self.rx
        rx.buf = bytearray()
        rx.buf_index = 0
        rx.expected_length = mavlink.HEADER_LEN_V1 + 2
        rx.have_prefix_error = False
        try:
            msgs = rx.parse_buffer(datagram) or []
        except Exception:  # noqa: BLE001 - any decoder failure is a dropped datagram
            self.stats.rx_bad += 1
            return []
        out = []
        for m in msgs:
            # Unknown message ids cannot be CRC-checked (no CRC_EXTRA): dropped as malformed.
            if isinstance(m, mavlink.MAVLink_bad_data | mavlink.MAVLink_unknown):
                self.stats.rx_bad += 1
            elif self.accept(m):
                out.append(m)
        if rx.buf_len() > 0:  # a truncated frame at the end of the datagram
            self.stats.rx_bad += 1
        self.stats.rx_frames += len(out)
        return out

    def authentic(self, msgs: list[MAVLinkMessage]) -> bool:
        """Whether accepted frames may decide whom a `udpin` link answers: always without
        signing; with it only if one of them is signed (a frame accepted unsigned, RADIO_STATUS,
        never moves the replies to its sender)."""
        if self.signing is None or self.signing.key is None:
            return True
        return any(is_signed(m.get_msgbuf()) for m in msgs)

    def accept(self, msg: MAVLinkMessage) -> bool:
        """False (counted) if signing is on and the frame is not acceptably signed."""
        sg = self.signing
        if sg is None or sg.key is None:
            return True
        why = sg.verify(
            msg.get_msgbuf(), msg.get_msgId(), msg.get_srcSystem(), msg.get_srcComponent()
        )
        if why is None:
            return True
        self.stats.rx_rejected += 1
        return False
