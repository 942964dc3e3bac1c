"""MAVLink 2 framing with pymavlink's `ardupilotmega` dialect (which includes `common`).

The dialect is imported explicitly (never chosen by an environment variable). One `Codec`
per link: it numbers outgoing frames and parses each UDP datagram on its own, so a truncated
or corrupt datagram cannot swallow the next one. MAVLink 1 frames are parsed too.
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

MAVLinkMessage = mavlink.MAVLink_message


@dataclass
class CodecStats:
    """Counters for one link: frames decoded, bytes or frames dropped as malformed."""

    rx_frames: int = 0
    rx_bad: int = 0
    tx_frames: int = 0
    tx_bytes: int = 0


class Codec:
    """Encode our messages as (system, component) and decode datagrams from the link."""

    def __init__(self, system_id: int, component_id: int):
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
            else:
                out.append(m)
        if rx.buf_len() > 0:  # a truncated frame at the end of the datagram
            self.stats.rx_bad += 1
        self.stats.rx_frames += len(out)
        return out
