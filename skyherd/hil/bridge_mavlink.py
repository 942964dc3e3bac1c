"""The few MAVLink frames a simulator exchanges with PX4, packed and parsed without pymavlink.

PX4's simulator interface (`simulator_mavlink`) speaks plain MAVLink over one TCP stream:
the simulator sends HIL_SENSOR, HIL_GPS and HIL_STATE_QUATERNION and PX4 answers with
HIL_ACTUATOR_CONTROLS (and a HEARTBEAT, and one COMMAND_LONG asking for ground truth).
pymavlink packs and parses these correctly but spends tens of µs on each; at 250 sensor
frames per simulated second and a 20× speed-up that is the whole budget. Here each
message is one precompiled `struct.Struct` and the checksum is `fastcrc` (a pymavlink
dependency), CRC-16/MCRF4XX = MAVLink's X.25 checksum.

The wire layouts (field order, crc_extra, msgid) are read from pymavlink's `common`
dialect at import time, so they cannot drift from the published definitions; the tests
decode every frame built here with pymavlink and encode every frame parsed here with it.

MAVLink 2 framing (mavlink.io "Packet Serialization"):
  0xFD len incompat compat seq sysid compid msgid(3, LE) payload[len] crc(2, LE)
  with trailing zero bytes of the payload dropped (at least one byte kept), and
  crc = X.25 over everything after the 0xFD plus the message's crc_extra byte.
MAVLink 1: 0xFE len seq sysid compid msgid payload[len] crc.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from fastcrc import crc16
from pymavlink.dialects.v20 import common as _mav

from skyherd.flight.mavlink.wire import CRC as _CRC
from skyherd.flight.mavlink.wire import HDR_V2 as _HDR_V2
from skyherd.flight.mavlink.wire import STX_V1, STX_V2


def _layout(cls, expected_fields: list[str]) -> tuple[int, int, struct.Struct]:
    """(msgid, crc_extra, payload Struct) of a pymavlink message class; checks field order."""
    if list(cls.ordered_fieldnames) != expected_fields:  # the indexing below relies on it
        raise ImportError(f"pymavlink {cls.msgname} wire order changed: {cls.ordered_fieldnames}")
    return cls.id, cls.crc_extra, struct.Struct(cls.unpacker.format)


HIL_SENSOR_ID, HIL_SENSOR_CRC, HIL_SENSOR = _layout(
    _mav.MAVLink_hil_sensor_message,
    ["time_usec", "xacc", "yacc", "zacc", "xgyro", "ygyro", "zgyro", "xmag", "ymag", "zmag"]
    + ["abs_pressure", "diff_pressure", "pressure_alt", "temperature", "fields_updated", "id"],
)
HIL_GPS_ID, HIL_GPS_CRC, HIL_GPS = _layout(
    _mav.MAVLink_hil_gps_message,
    ["time_usec", "lat", "lon", "alt", "eph", "epv", "vel", "vn", "ve", "vd", "cog"]
    + ["fix_type", "satellites_visible", "id", "yaw"],
)
HIL_STATE_Q_ID, HIL_STATE_Q_CRC, HIL_STATE_Q = _layout(
    _mav.MAVLink_hil_state_quaternion_message,
    ["time_usec", "attitude_quaternion", "rollspeed", "pitchspeed", "yawspeed", "lat", "lon"]
    + ["alt", "vx", "vy", "vz", "ind_airspeed", "true_airspeed", "xacc", "yacc", "zacc"],
)
HIL_ACT_ID, HIL_ACT_CRC, HIL_ACT = _layout(
    _mav.MAVLink_hil_actuator_controls_message, ["time_usec", "flags", "controls", "mode"]
)
HEARTBEAT_ID, HEARTBEAT_CRC, HEARTBEAT = _layout(
    _mav.MAVLink_heartbeat_message,
    ["custom_mode", "type", "autopilot", "base_mode", "system_status", "mavlink_version"],
)
COMMAND_LONG_ID, COMMAND_LONG_CRC, COMMAND_LONG = _layout(
    _mav.MAVLink_command_long_message,
    ["param1", "param2", "param3", "param4", "param5", "param6", "param7", "command"]
    + ["target_system", "target_component", "confirmation"],
)
# crc_extra of every message id this module can check; frames of other ids are skipped.
CRC_EXTRA: dict[int, int] = {
    HIL_SENSOR_ID: HIL_SENSOR_CRC,
    HIL_GPS_ID: HIL_GPS_CRC,
    HIL_STATE_Q_ID: HIL_STATE_Q_CRC,
    HIL_ACT_ID: HIL_ACT_CRC,
    HEARTBEAT_ID: HEARTBEAT_CRC,
    COMMAND_LONG_ID: COMMAND_LONG_CRC,
}
MAV_CMD_SET_MESSAGE_INTERVAL = 511
# HIL_SENSOR fields_updated bits (PX4 SimulatorMavlink.hpp, SensorSource)
FIELDS_ACCEL = 0b111
FIELDS_GYRO = 0b111000
FIELDS_MAG = 0b111000000
FIELDS_BARO = 0b1101000000000  # abs_pressure, pressure_alt, temperature
FIELDS_DIFF_PRESS = 0b10000000000


@dataclass
class Framer:
    """Builds MAVLink 2 frames from one sender (sysid, compid), counting `seq`."""

    sysid: int = 1
    compid: int = 200  # the component Gazebo's mavlink_interface uses for the simulator
    seq: int = 0

    def frame(self, msgid: int, crc_extra: int, payload: bytes) -> bytes:
        n = len(payload)
        while n > 1 and payload[n - 1] == 0:  # MAVLink 2 payload truncation
            n -= 1
        hdr = _HDR_V2.pack(
            STX_V2, n, 0, 0, self.seq, self.sysid, self.compid, msgid & 0xFFFF, msgid >> 16
        )
        self.seq = (self.seq + 1) & 0xFF
        body = hdr[1:] + payload[:n]
        return hdr + payload[:n] + _CRC.pack(crc16.mcrf4xx(body + bytes((crc_extra,))))


@dataclass
class Frame:
    """One checked frame: message id, sender, payload padded to the full message length."""

    msgid: int
    sysid: int
    compid: int
    payload: bytes


class FrameParser:
    """Splits a byte stream into checked MAVLink 1 / 2 frames of the ids in CRC_EXTRA.

    Bytes before a start marker, frames with a bad checksum and frames of unknown ids are
    dropped (counted in `dropped`); a frame split over two reads is kept until complete.
    Signed MAVLink 2 frames (incompat flag 0x01) carry 13 more bytes, skipped here.
    """

    _FULL_LEN = {
        HIL_SENSOR_ID: HIL_SENSOR.size,
        HIL_GPS_ID: HIL_GPS.size,
        HIL_STATE_Q_ID: HIL_STATE_Q.size,
        HIL_ACT_ID: HIL_ACT.size,
        HEARTBEAT_ID: HEARTBEAT.size,
        COMMAND_LONG_ID: COMMAND_LONG.size,
    }

    def __init__(self) -> None:
        self._buf = bytearray()
        self.dropped = 0

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf += data
        out: list[Frame] = []
        i = 0
        n = len(buf)
        while i < n:
            stx = buf[i]
            if stx != STX_V2 and stx != STX_V1:
                j1, j2 = buf.find(b"\xfd", i), buf.find(b"\xfe", i)
                js = [j for j in (j1, j2) if j >= 0]
                if not js:
                    self.dropped += n - i
                    i = n
                    break
                self.dropped += min(js) - i
                i = min(js)
                continue
            if n - i < 3:
                break
            plen = buf[i + 1]
            if stx == STX_V2:
                if n - i < 10:
                    break
                signed = buf[i + 2] & 0x01
                total = 10 + plen + 2 + (13 if signed else 0)
                if n - i < total:
                    break
                msgid = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
                hdr_end = i + 10
                sysid, compid = buf[i + 5], buf[i + 6]
            else:
                total = 6 + plen + 2
                if n - i < total:
                    break
                msgid = buf[i + 5]
                hdr_end = i + 6
                sysid, compid = buf[i + 3], buf[i + 4]
            extra = CRC_EXTRA.get(msgid)
            end = hdr_end + plen
            if extra is None:
                self.dropped += total
                i += total
                continue
            crc = crc16.mcrf4xx(bytes(buf[i + 1 : end]) + bytes((extra,)))
            if crc != (buf[end] | (buf[end + 1] << 8)):
                self.dropped += 1  # resynchronise on the next marker
                i += 1
                continue
            full = self._FULL_LEN[msgid]
            payload = bytes(buf[hdr_end:end])
            if len(payload) < full:
                payload += bytes(full - len(payload))
            out.append(Frame(msgid, sysid, compid, payload[:full]))
            i += total
        del buf[:i]
        if len(buf) > 65536:  # garbage without a frame end: never grow without bound
            self.dropped += len(buf)
            buf.clear()
        return out
