"""Scripted stand-ins for the autopilot side of both simulator protocols (tests and bench).

They follow the published protocols byte for byte, so the bridges can be tested without
PX4 or ArduPilot installed (neither is on a package registry):

- `ArduPilotJsonPeer` is libraries/SITL/SIM_JSON.cpp re-told in Python: the same
  `servo_packet_16` (little-endian uint16 magic 18458, uint16 frame_rate, uint32
  frame_count, uint16 pwm[16]), frame_rate ramped by 1 Hz a frame towards the target as
  `adjust_frame_time` does, frame_count advanced only when a reply was parsed, the servos
  sent again after 1 s without a reply, and the reply read the way `recv_fdm` /
  `parse_sensors` read it: '\\n' → NUL, the text between the last two NULs, each key found
  by strstr, numbers by atof and vectors by sscanf("[%f, %f, %f]") (`scan_vector`).
- `Px4SimPeer` is PX4's simulator_mavlink seen from the wire: it connects to TCP 4560+N,
  sends a HEARTBEAT and the COMMAND_LONG asking for HIL_STATE_QUATERNION, and answers each
  HIL_SENSOR with one HIL_ACTUATOR_CONTROLS stamped with that sensor's time_usec (what PX4's
  lockstep scheduler does); frames are encoded and decoded by pymavlink.

Both fly a small deterministic controller on what they are told (altitude hold with all
four motors, a yaw pattern), so a trajectory depends on every byte exchanged.
"""

from __future__ import annotations

import math
import re
import socket
import struct
import time
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

SERVO_16 = struct.Struct("<HHI16H")
UDP_TIMEOUT_S = 0.1  # SIM_JSON.cpp UDP_TIMEOUT_MS
RESEND_AFTER_S = 1.0  # SIM_JSON.cpp: "wait_ms > 1000" → output_servos again

# ---- ArduPilot's reading of a JSON line ---------------------------------------------------
# (section, key, kind, required) in SIM_JSON.h keytable order
KEYTABLE = [
    ("", "timestamp", "double", True),
    ("imu", "gyro", "vec3f", True),
    ("imu", "accel_body", "vec3f", True),
    ("", "position", "vec3d", True),
    ("", "attitude", "vec3f", False),
    ("", "quaternion", "quat", False),
    ("", "velocity", "vec3f", True),
    ("", "rng_1", "float", False),
    ("", "airspeed", "float", False),
]
_STRTOD = re.compile(r"[ \t\n\r\f\v]*([+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|inf|nan))", re.I)


def _atof(s: str) -> float:
    m = _STRTOD.match(s)
    return float(m.group(1)) if m else 0.0


def scan_vector(s: str, n: int, single: bool) -> list[float] | None:
    """sscanf(s, "[%f, %f, …]") with n conversions: the values, or None if fewer matched.

    Literal '[' and ',' must match the very next character; the space in ", " and each
    %f skip any whitespace. single=True rounds to float32 as %f does (%lf keeps doubles).
    """
    if not s.startswith("["):
        return None
    i, out = 1, []
    for k in range(n):
        m = _STRTOD.match(s, i)
        if not m:
            return None
        v = float(m.group(1))
        out.append(float(np.float32(v)) if single else v)
        i = m.end()
        if k < n - 1:
            if i >= len(s) or s[i] != ",":
                return None
            i += 1
    return out


def parse_sensors(line: str) -> dict[str, object] | None:
    """SIM_JSON.cpp parse_sensors(): {key: value} of the keys found, None on failure."""
    found: dict[str, object] = {}
    for section, key, kind, required in KEYTABLE:
        p = line.find(section)
        if p < 0:
            if required:
                return None
            continue
        p += len(section) + 1
        q = line.find(key, p)
        if q < 0:
            if required:
                return None
            continue
        v = line[q + len(key) + 2 :]
        if kind in ("double", "float"):
            found[key] = _atof(v) if kind == "double" else float(np.float32(_atof(v)))
        else:
            n = 4 if kind == "quat" else 3
            vec = scan_vector(v, n, single=kind != "vec3d")
            if vec is None:
                return found  # ArduPilot returns the bitmask so far: a partial read
            found[key] = vec
    if "quaternion" not in found and "attitude" not in found:
        return None
    return found


class RecvFdm:
    """SIM_JSON.cpp recv_fdm()'s buffer: returns the parsed line once one is complete."""

    def __init__(self) -> None:
        self.buf = bytearray()

    def feed(self, data: bytes) -> dict[str, object] | None:
        self.buf += data.replace(b"\n", b"\0")
        b = self.buf
        p2 = b.rfind(b"\0")
        if p2 <= 0:
            return None
        p1 = b.rfind(b"\0", 0, p2)
        if p1 < 0:
            return None
        line = b[p1 + 1 : p2].decode("ascii", "replace")
        del b[:p2]
        return parse_sensors(line)


# ---- a deterministic controller for both peers ---------------------------------------------
@dataclass
class HoverScript:
    """Altitude hold at `target_alt` [m] with all motors, plus a yaw pattern (quad X).

    u_i = hover + kp (alt* − alt) − kd v_up  ± yaw  (± by rotor spin), clipped to [0, 1].
    """

    target_alt: float = 3.0
    hover: float = 0.68
    kp: float = 0.08
    kd: float = 0.12
    yaw_amp: float = 0.02
    yaw_period_s: float = 4.0
    spin_up_s: float = 0.5

    def motors(self, t: float, alt: float, v_up: float) -> list[float]:
        if t < self.spin_up_s:
            return [0.0] * 4
        c = self.hover + self.kp * (self.target_alt - alt) - self.kd * v_up
        y = self.yaw_amp * math.sin(2.0 * math.pi * t / self.yaw_period_s)
        spin = (1.0, 1.0, -1.0, -1.0)
        return [min(1.0, max(0.0, c + s * y)) for s in spin]


@dataclass
class ArduPilotJsonPeer:
    """ArduPilot's JSON side (see module docstring) against 127.0.0.1:port."""

    port: int
    rate_hz: float = 400.0  # SIM_RATE_HZ: frame_rate ramps to it
    start_rate_hz: float = 300.0
    speedup: float = 0.0  # wall pacing of the peer: 0 = none, 1 = real time
    script: HoverScript = field(default_factory=HoverScript)
    frame_count: int = 0
    received: list[dict] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.fdm = RecvFdm()
        self._rate = self.start_rate_hz
        self._state: dict | None = None
        self._wall0: float | None = None

    def close(self) -> None:
        self.sock.close()

    def packet(self, pwm: list[int]) -> bytes:
        return SERVO_16.pack(18458, int(self._rate), self.frame_count, *pwm)

    def pwm(self) -> list[int]:
        s = self._state
        if s is None:
            u = [0.0] * 4
        else:
            u = self.script.motors(s["timestamp"], -s["position"][2], -s["velocity"][2])
        return [int(1000 + 1000 * v) for v in u] + [0] * 12

    def exchange(self, packet: bytes, max_wait_s: float = 5.0) -> dict | None:
        """output_servos + recv_fdm: send, wait for a parsed reply (re-send after 1 s)."""
        self.sock.sendto(packet, ("127.0.0.1", self.port))
        self.sock.settimeout(UDP_TIMEOUT_S)
        waited, wait_ms = 0.0, UDP_TIMEOUT_S
        while True:
            try:
                data = self.sock.recv(65000)
            except TimeoutError:
                waited += UDP_TIMEOUT_S
                wait_ms += UDP_TIMEOUT_S
                if waited >= max_wait_s:
                    return None
                if wait_ms > RESEND_AFTER_S + 1e-9:  # "resending servos"
                    wait_ms = 0.0
                    self.sock.sendto(packet, ("127.0.0.1", self.port))
                continue
            parsed = self.fdm.feed(data)
            if parsed is not None:
                return parsed

    def run(self, frames: int) -> list[dict]:
        """Fly `frames` frames; every parsed reply is appended to `received`."""
        for _ in range(frames):
            parsed = self.exchange(self.packet(self.pwm()))
            if parsed is None:
                raise TimeoutError(f"no JSON reply to frame {self.frame_count}")
            self._state = parsed
            self.received.append(parsed)
            self.frame_count += 1
            self._rate = min(self.rate_hz, self._rate + 1.0)
            self._pace(parsed["timestamp"])
        return self.received

    def _pace(self, sim_t: float) -> None:
        if self.speedup <= 0:
            return
        now = time.monotonic()
        if self._wall0 is None:
            self._wall0 = now - sim_t / self.speedup
        lag = self._wall0 + sim_t / self.speedup - now
        if lag > 0:
            time.sleep(lag)

    def restart(self) -> None:
        """What a restarted ArduPilot looks like: frame_count and frame_rate from scratch."""
        self.frame_count = 0
        self._rate = self.start_rate_hz
        self._state = None
        self.fdm = RecvFdm()


# ---- PX4 ------------------------------------------------------------------------------------
@dataclass
class Px4SimPeer:
    """PX4 simulator_mavlink's side of TCP 4560+N (see module docstring)."""

    port: int
    script: HoverScript = field(default_factory=HoverScript)
    sensors: list = field(default_factory=list)  # decoded HIL_SENSOR messages
    gps: list = field(default_factory=list)
    truth: list = field(default_factory=list)

    def __post_init__(self) -> None:
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.mav.robust_parsing = True
        self.sock: socket.socket | None = None
        self._alt = 0.0
        self._v_up = 0.0
        self._baro_alt0: float | None = None

    def connect(self, timeout_s: float = 10.0) -> None:
        t_end = time.monotonic() + timeout_s
        while True:
            try:
                self.sock = socket.create_connection(("127.0.0.1", self.port), timeout=1.0)
                break
            except OSError:
                if time.monotonic() > t_end:
                    raise
                time.sleep(0.01)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        hb = self.mav.heartbeat_encode(2, 12, 0, 0, 0).pack(self.mav)
        cmd = self.mav.command_long_encode(0, 0, 511, 0, 115, 5000, 0, 0, 0, 0, 0).pack(self.mav)
        self.sock.sendall(hb + cmd)

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def controls(self, t: float) -> list[float]:
        return self.script.motors(t, self._alt, self._v_up) + [0.0] * 12

    def run(self, steps: int, answer: bool = True, timeout_s: float = 10.0) -> int:
        """Answer `steps` HIL_SENSOR frames (or only read them, answer=False)."""
        assert self.sock is not None
        self.sock.settimeout(timeout_s)
        done = 0
        while done < steps:
            data = self.sock.recv(65536)
            if not data:
                raise ConnectionError("bridge closed the connection")
            msgs = self.mav.parse_buffer(data) or []
            for m in msgs:
                kind = m.get_type()
                if kind == "HIL_GPS":
                    self.gps.append(m)
                    self._v_up = -m.vd / 100.0
                elif kind == "HIL_STATE_QUATERNION":
                    self.truth.append(m)
                elif kind == "HIL_SENSOR":
                    self.sensors.append(m)
                    if m.fields_updated & 0b1101000000000:
                        if self._baro_alt0 is None:
                            self._baro_alt0 = m.pressure_alt
                        self._alt = m.pressure_alt - self._baro_alt0
                    if answer:
                        t = m.time_usec * 1e-6
                        out = self.mav.hil_actuator_controls_encode(
                            m.time_usec, self.controls(t), 1 | 128, 1
                        ).pack(self.mav)
                        self.sock.sendall(out)
                    done += 1
        return done
