"""MAVLink 2 framing with pymavlink's `ardupilotmega` dialect (which includes `common`).

The dialect is imported explicitly (never chosen by an environment variable). One `Codec`
per link: it numbers outgoing frames and parses each UDP datagram on its own, so a truncated
or corrupt datagram cannot swallow the next one. MAVLink 1 frames are parsed too. With a
`Signing` whose key is set, outgoing frames are signed and incoming ones verified
(flight.mavlink.signing); rejected frames are counted in `rx_rejected`.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from flight.mavlink.signing import Signing

MAVLinkMessage = mavlink.MAVLink_message


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

    def pack(self, msg: MAVLinkMessage) -> bytes:
        """Frame one message (MAVLink 2) with the next sequence number."""
        buf = bytes(msg.pack(self.tx))
        if self.signing is not None and self.signing.key is not None:
            buf = self.signing.sign(buf, self.link_id)
        self.tx.seq = (self.tx.seq + 1) % 256
        self.stats.tx_frames += 1
        self.stats.tx_bytes += len(buf)
        return buf

    def parse(self, datagram: bytes) -> list[MAVLinkMessage]:
        """Decode every valid frame in one datagram; malformed bytes are counted and dropped."""
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
