"""skyherd's physics as ArduPilot's simulator: the JSON backend (`--model JSON`), over UDP.

ArduPilot (libraries/SITL/SIM_JSON.cpp) sends one binary servo packet per physics frame to
UDP 9002 (+10 per instance `-I N`), little-endian:
  uint16 magic (18458: 16 channels, 29569: 32), uint16 frame_rate [Hz], uint32 frame_count,
  uint16 pwm[16 | 32] [µs]
and waits for one line of JSON back. We bind 127.0.0.1:9002+10N and answer the sender with
  \\n{"timestamp":s,"imu":{"gyro":[p,q,r],"accel_body":[x,y,z]},"position":[n,e,d],
  "quaternion":[w,x,y,z],"velocity":[vn,ve,vd]}\\n            (+ "airspeed" for a plane)
gyro body FRD [rad/s], accel_body the specific force [m/s²] (ground contact included),
position NED [m] about home with the ground at down = 0, quaternion body → NED.

How ArduPilot reads it decides the format: it takes the last complete line between two
'\\n', finds every key by substring search and reads vectors with
sscanf("[%f, %f, %f]") right after `"key":` — so no space after ':' and no other key
whose name contains "gyro", "position", "velocity"… The timestamp is printed with 9
decimals: ArduPilot integrates the differences.

Lockstep on frame_count: each new frame_count steps the physics once by 1/frame_rate of
that very packet (ArduPilot ramps frame_rate towards SIM_RATE_HZ); a repeated frame_count
(ArduPilot re-sends its servos after 1 s without an answer) does not step: the cached reply
is sent again only when it is older than `resend_after_s` of wall time (answering every
duplicate would shift lockstep by a frame; answering none deadlocks after a lost reply);
a frame_count going back means ArduPilot restarted: the physics is reset.

One CPU for the pair (runio.pin, `pin_cpu`): the thread that opens the bridge, or runs `serve`,
is the lockstep thread and is kept on the chosen CPU while the bridge is open (its other threads,
and the process, keep every CPU); the autopilot belongs on the same CPU (hil/autopilot_sitl.py
starts it there; one started by hand: `taskset -c CPU arducopter ...`).
"""

from __future__ import annotations

import ctypes
import math
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.fixedwing.jsbsim_model import Surfaces
from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.flight.quadrotor import QuadrotorParams
from skyherd.flight.state import VehicleState
from skyherd.hil.bridge_format import compiled_for, make_template, quad_frame
from skyherd.hil.bridge_net import bind_socket
from skyherd.hil.bridge_physics import PlaneBody, QuadBody
from skyherd.runio import ports
from skyherd.runio.pin import choose_cpu, cpu_list, pin_thread
from skyherd.runio.process import say

JSON_BASE_PORT = ports.JSON_BASE  # runio.ports: every port an instance owns
PORT_STRIDE = ports.JSON_STRIDE  # ArduPilot's -I N moves every port by 10 N
MAGIC_16 = 18458
MAGIC_32 = 29569
_HDR = struct.Struct("<HHI")
PACKET_BYTES = {MAGIC_16: 8 + 2 * 16, MAGIC_32: 8 + 2 * 32}
AIRFRAMES = ("quadrotor", "fixedwing")

_FMT_BODY = (
    '"timestamp":%.9f,"imu":{"gyro":[%.9g,%.9g,%.9g],"accel_body":[%.9g,%.9g,%.9g]},'
    '"position":[%.9g,%.9g,%.9g],"quaternion":[%.9g,%.9g,%.9g,%.9g],"velocity":[%.9g,%.9g,%.9g]'
)
REPLY_FMT = "\n{" + _FMT_BODY + "}\n"
REPLY_FMT_AIRSPEED = "\n{" + _FMT_BODY + ',"airspeed":%.9g}\n'
# the same formats as bytes: the reply is formatted straight into the datagram's bytes
_REPLY_B = REPLY_FMT.encode()
_REPLY_AIRSPEED_B = REPLY_FMT_AIRSPEED.encode()
_REPLY_TEMPLATE = make_template(REPLY_FMT)  # the quadrotor's reply, formatted compiled
_TIMEVAL = struct.Struct("@ll")  # struct timeval of SO_RCVTIMEO
_UNSET = object()
# connect(fd, {AF_UNSPEC}, len): how a connected UDP socket is disconnected (Python's own
# connect takes no AF_UNSPEC address)
_libc_connect = ctypes.CDLL(None, use_errno=True).connect
_libc_connect.argtypes = (ctypes.c_int, ctypes.c_char_p, ctypes.c_uint)
_libc_connect.restype = ctypes.c_int
_AF_UNSPEC_ADDR = bytes(16)


def json_port(instance: int) -> int:
    """UDP port ArduPilot `-I instance` sends its servo packets to."""
    port = ports.json_port(instance)
    if not (0 <= instance and port <= 65535):
        raise ValueError(f"instance {instance} gives no valid UDP port")
    return port


@dataclass(frozen=True)
class JsonBridgeConfig:
    """Settings of the ArduPilot JSON bridge (saved with a run).

    pwm_min, pwm_max   [µs] motor PWM for command 0 and 1 (ArduCopter MOT_PWM_MIN/MAX)
    resend_after_s     [s wall] a duplicate frame gets the cached reply only past this age
    channels           1-based servo channels of aileron, elevator, throttle, rudder
                       (ArduPlane's default SERVOn_FUNCTION 4, 19, 70, 21 on 1..4)
    """

    pwm_min: float = 1000.0
    pwm_max: float = 2000.0
    resend_after_s: float = 0.5
    channels: tuple[int, int, int, int] = (1, 2, 3, 4)

    def __post_init__(self) -> None:
        if not (self.pwm_max > self.pwm_min > 0):
            raise ValueError("need 0 < pwm_min < pwm_max")
        if not self.resend_after_s > 0:
            raise ValueError("resend_after_s must be > 0")
        if sorted(self.channels) != sorted(set(self.channels)) or not all(
            1 <= c <= 16 for c in self.channels
        ):
            raise ValueError(f"channels must be 4 distinct numbers in 1..16, got {self.channels}")


@dataclass
class JsonStats:
    frames: int = 0  # physics steps taken
    duplicates: int = 0  # repeated frame_count (not stepped)
    resends: int = 0  # cached replies sent again
    restarts: int = 0  # frame_count went back: physics reset
    bad_packets: int = 0  # wrong size or magic, frame_rate 0
    cpu: int | None = None  # the CPU the lockstep thread was pinned to (None: not pinned)


@dataclass
class ArduPilotJsonBridge:
    """skyherd's quadrotor or JSBSim plane as the physics of one ArduPilot SITL instance.

    `open()` binds the socket, `step_once(timeout_s)` handles one packet, `serve()` loops;
    `state` is the true VehicleState after the last step (for the camera and the world).
    `pin_cpu`: "auto", "off" or a CPU number for the lockstep thread (runio.pin.choose_cpu;
    ValueError if that CPU is not allowed); `cpu` is the choice (None: not pinned).
    """

    airframe: str = "quadrotor"
    instance: int = 0
    seed: int = 0
    home: Home = DEFAULT_HOME
    config: JsonBridgeConfig = field(default_factory=JsonBridgeConfig)
    quad_params: QuadrotorParams | None = None
    host: str = "127.0.0.1"
    pin_cpu: str | int = "auto"
    stats: JsonStats = field(default_factory=JsonStats, init=False)

    def __post_init__(self) -> None:
        if self.airframe not in AIRFRAMES:
            raise ValueError(f"airframe {self.airframe!r}: choose one of {AIRFRAMES}")
        self.port = json_port(self.instance)
        self.cpu = choose_cpu(self.pin_cpu, self.instance)
        self._held: tuple[int, frozenset[int]] | None = None  # (thread id, its CPUs before)
        # seed: kept for the API and the run record; the JSON physics has no noise of its
        # own (ArduPilot adds its SIM_*_RND sensor noise itself).
        if self.airframe == "quadrotor":
            self.body: QuadBody | PlaneBody = QuadBody(self.quad_params)
        else:
            self.body = PlaneBody(self.home)
        self._rx = np.zeros(256, dtype=np.uint8)
        self._tx = np.zeros(512, dtype=np.uint8)  # the compiled reply (+ its digit scratch)
        self._sock: socket.socket | None = None
        self._peer = None
        self._last_fc: int | None = None
        self._reply = b""
        self._reply_wall = 0.0
        self._timeout: object = _UNSET  # the socket's receive timeout [s] (None: forever)
        # the quadrotor's step arguments, bound once (the model's arrays change in place), and
        # its compiled frame for exactly their types (bridge_format.compiled_for)
        self._quad = None
        if isinstance(self.body, QuadBody):
            b, c = self.body, self.config
            m = b.model
            self._quad = (c.pwm_min, c.pwm_max, m.x, m.aux, m.p, b.u, b.params.physics_dt, b.out)
            args = (self._rx, *self._quad[:7], 0.0, b.out, 0.0, _REPLY_TEMPLATE, self._tx)
            self._quad_frame = compiled_for(quad_frame, args)

    # ---- socket ---------------------------------------------------------------------------
    def open(self) -> ArduPilotJsonBridge:
        if self._sock is None:
            self._sock = bind_socket(socket.SOCK_DGRAM, self.host, self.port, self.instance)
            self._timeout = _UNSET
            self._peer = None
            self._hold_cpu()
        return self

    def _hold_cpu(self) -> None:
        """Keep the calling thread, the lockstep's, on `cpu` (a thread held before gets its
        CPUs back); said once. The kernel refusing: one warning, and the bridge runs unpinned."""
        tid = threading.get_native_id()
        if self.cpu is None or (self._held is not None and self._held[0] == tid):
            return
        said = self.stats.cpu is not None
        self._let_go()
        before = pin_thread(self.cpu, tid)
        if before is None:  # warned: unpinned from now on
            self.cpu = None
            return
        self._held, self.stats.cpu = (tid, before), self.cpu
        if not said:
            say(f"skyherd: ArduPilot JSON bridge (instance {self.instance}): lockstep thread on "
                f"CPU {self.cpu} (--pin-cpu {self.pin_cpu}; allowed {cpu_list(before)}); run the "
                f"autopilot on it too: taskset -c {self.cpu} arducopter ...")  # fmt: skip

    def _let_go(self) -> None:
        """Give the held thread its CPUs back (quietly: it may have ended)."""
        if self._held is not None:
            tid, before = self._held
            self._held = None
            pin_thread(before, tid, warn=lambda _: None)

    def _wait_at_most(self, sock: socket.socket, timeout_s: float | None) -> None:
        """Let `recvfrom` itself wait at most timeout_s (SO_RCVTIMEO; None: forever) on a
        blocking socket: a frame is then one recvfrom and one sendto. Python's own timeout
        would add a poll() per receive, and setting it per frame an ioctl."""
        if timeout_s == self._timeout:  # (_UNSET equals nothing)
            return
        self._timeout = timeout_s
        sock.settimeout(None)
        us = 0 if timeout_s is None else max(1, round(timeout_s * 1e6))
        sock.setsockopt(
            socket.SOL_SOCKET, socket.SO_RCVTIMEO, _TIMEVAL.pack(us // 1_000_000, us % 1_000_000)
        )

    def open_port(self) -> ArduPilotJsonBridge:
        """The common bridge API's name for `open` (see hil/bridge_select.py)."""
        return self.open()

    def close(self) -> None:
        self._let_go()
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> ArduPilotJsonBridge:
        return self.open()

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- physics --------------------------------------------------------------------------
    @property
    def t(self) -> float:
        """Simulation time [s] (sum of the stepped frames' 1/frame_rate)."""
        return self.body.t

    @property
    def state(self) -> VehicleState:
        return self.body.state()

    def reset(self) -> None:
        self.body.reset()
        self._last_fc = None
        self._reply = b""

    def handle(self, nbytes: int, now_wall: float) -> tuple[bool, bytes | None]:
        """Handle the packet in the receive buffer: (stepped, reply to send or None)."""
        rx = self._rx
        if nbytes < 8:
            self.stats.bad_packets += 1
            return False, None
        magic, rate, fc = _HDR.unpack_from(rx)
        if PACKET_BYTES.get(magic) != nbytes or rate == 0:
            self.stats.bad_packets += 1
            return False, None
        last = self._last_fc
        if last is not None:
            if fc == last:
                self.stats.duplicates += 1
                if now_wall - self._reply_wall >= self.config.resend_after_s:
                    self._reply_wall = now_wall
                    self.stats.resends += 1
                    return False, self._reply
                return False, None
            if fc < last:
                self.stats.restarts += 1
                self.body.reset()
        self._last_fc = fc
        dt = 1.0 / rate
        body = self.body
        quad = self._quad
        if quad is not None:
            pwm_min, pwm_max, x, aux, p, u, max_h, out = quad
            t = body.t = body.t + dt
            tx = self._tx
            n = self._quad_frame(rx, pwm_min, pwm_max, x, aux, p, u, dt, max_h, out, t, _REPLY_TEMPLATE, tx)  # fmt: skip
            # n < 0: a number the compiled conversion could not round for certain (rare)
            reply = tx[:n].tobytes() if n >= 0 else _REPLY_B % (t, *out.tolist())
        else:
            body.step(dt, self._surfaces(rx))
            reply = _REPLY_AIRSPEED_B % (body.t, *body.out.tolist(), body.airspeed)
        self.stats.frames += 1
        self._reply = reply
        self._reply_wall = now_wall
        return True, reply

    def _surfaces(self, rx: np.ndarray) -> Surfaces:
        def pwm(ch: int) -> int:
            return int(rx[6 + 2 * ch]) | (int(rx[7 + 2 * ch]) << 8)  # ch 1-based

        a, e, t, r = (pwm(c) for c in self.config.channels)

        def angle(v: int) -> float:  # ArduPilot: an unset servo (0) reads as 1500
            return 0.0 if v == 0 else (v - 1500) / 500.0

        return Surfaces(
            aileron=angle(a),
            elevator=angle(e),
            rudder=angle(r),
            throttle=(t - self.config.pwm_min) / (self.config.pwm_max - self.config.pwm_min),
        ).clipped()

    # ---- loop -----------------------------------------------------------------------------
    def step_once(self, timeout_s: float | None = 1.0) -> bool:
        """Wait up to timeout_s (wall) for one packet and answer it; True if physics stepped."""
        sock = self._sock or self.open()._sock
        if timeout_s != self._timeout:  # (_UNSET equals nothing)
            self._wait_at_most(sock, timeout_s)
        return bool(self._one_packet(sock))

    def serve(
        self,
        sim_duration_s: float | None = None,
        max_frames: int | None = None,
        idle_timeout_s: float | None = None,
        on_step: Callable[[ArduPilotJsonBridge], bool | None] | None = None,
    ) -> JsonStats:
        """Answer ArduPilot until sim time, frame count or a wall-time idle gap runs out.

        on_step(bridge) runs after each physics step; returning True stops the loop.
        """
        sock = self.open()._sock
        self._hold_cpu()  # this thread runs the lockstep
        self._wait_at_most(sock, idle_timeout_s)
        one = self._one_packet
        t_end = math.inf if sim_duration_s is None else sim_duration_s
        n_end = math.inf if max_frames is None else max_frames
        while self.body.t < t_end and self.stats.frames < n_end:
            stepped = one(sock)
            if stepped is None:  # the idle gap ran out
                break
            if stepped and on_step is not None and on_step(self):
                break
        return self.stats

    def _one_packet(self, sock: socket.socket) -> bool | None:
        """Receive one packet and answer it: True if the physics stepped, None if the wait ran
        out. After the first answer the socket is connected to the autopilot's address, so a
        frame builds and parses no address (`recv_into` / `send`); the wait running out or the
        autopilot gone (a refused send) disconnects it, so that a restarted autopilot, sending
        from another port, is heard again."""
        try:
            if self._peer is not None:
                nbytes, addr = sock.recv_into(self._rx), self._peer
            else:
                nbytes, addr = sock.recvfrom_into(self._rx)
        except (TimeoutError, BlockingIOError):  # SO_RCVTIMEO ran out (EAGAIN)
            self._disconnect(sock)
            return None
        except ConnectionRefusedError:  # the autopilot's port is closed (ICMP)
            self._disconnect(sock)
            return False
        stepped, reply = self.handle(nbytes, time.monotonic())
        if reply is not None:
            if self._peer is None:
                sock.connect(addr)
                self._peer = addr
            try:
                sock.send(reply)
            except ConnectionRefusedError:
                self._disconnect(sock)
        return stepped

    def _disconnect(self, sock: socket.socket) -> None:
        """Dissolve the socket's association with the autopilot (connect to AF_UNSPEC): it
        receives from any sender again, and nothing already queued is lost."""
        if self._peer is not None:
            self._peer = None
            if _libc_connect(sock.fileno(), _AF_UNSPEC_ADDR, len(_AF_UNSPEC_ADDR)) != 0:
                raise OSError(ctypes.get_errno(), "cannot disconnect the JSON bridge's socket")
