"""skyherd's physics as PX4's simulator: the simulator_mavlink interface on TCP 4560+N.

PX4 started with PX4_SIM_MODEL=none_iris (instance -i N) connects to TCP 127.0.0.1:4560+N
and waits for a simulator. We listen there, and for every physics frame (default 250 Hz):
  → HIL_SENSOR            accel (specific force, body FRD) [m/s²], gyro [rad/s], mag [gauss],
                          abs_pressure [hPa], pressure_alt [m], temperature [°C];
                          fields_updated says which of them are new this frame
  → HIL_GPS               every gps_every frames (10 Hz): lat/lon [degE7], alt [mm AMSL],
                          velocity [cm/s], fix 3D
  → HIL_STATE_QUATERNION  every truth_every frames: the true state (PX4 logs it as ground truth)
  ← HIL_ACTUATOR_CONTROLS controls[0..3] = motors 1..4 in [0, 1] (none_iris: quad X, PX4 Iris
                          order, 1 FR CCW, 2 RL CCW, 3 FL CW, 4 RR CW)
Lockstep (PX4's lockstep scheduler): PX4's clock is the time_usec of our HIL_SENSOR, and it
answers each one with one HIL_ACTUATOR_CONTROLS stamped with that same time. We step the
physics only once that answer is in. Before PX4's controllers run (the first seconds of its
boot) it sends no actuator messages; until the first one arrives each frame waits at most
`boot_wait_s` of wall time and then steps with the motors off — exactly what Gazebo's
mavlink_interface does. From the first answer on, no answer means no step.
"""

from __future__ import annotations

import math
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from skyherd.flight.clock import Pacer
from skyherd.flight.geo import DEFAULT_HOME, Home, ned_to_geodetic
from skyherd.flight.quadrotor import QuadrotorParams
from skyherd.flight.state import VehicleState
from skyherd.hil import bridge_mavlink as wire
from skyherd.hil.bridge_net import bind_socket
from skyherd.hil.bridge_physics import O_ACCEL, O_GYRO, O_POS, O_QUAT, O_VEL, QuadBody
from skyherd.hil.bridge_sensors import (
    MagField,
    NoiseBlock,
    SensorNoise,
    body_from_ned,
    isa_pressure_pa,
    isa_temperature_c,
)
from skyherd.runio import ports

PX4_SIM_BASE_PORT = ports.PX4_SIM_BASE  # runio.ports: every port an instance owns
UTC_EPOCH_US = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z: HIL_GPS time = this + sim time


def px4_sim_port(instance: int) -> int:
    """TCP port PX4 `-i instance` connects its simulator_mavlink to."""
    port = ports.px4_sim_port(instance)
    if not (0 <= instance and port <= 65535):
        raise ValueError(f"instance {instance} gives no valid TCP port")
    return port


class Px4Timeout(TimeoutError):
    """PX4 stopped answering HIL_SENSOR within the configured wall time."""


@dataclass(frozen=True)
class Px4BridgeConfig:
    """Settings of the PX4 simulator bridge (saved with a run).

    rate_hz          physics and HIL_SENSOR rate [Hz] (PX4 needs >= 250)
    mag_every, baro_every, gps_every, truth_every   send those every k-th frame
    truth_max_hz     HIL_STATE_QUATERNION at most this often [Hz], whatever PX4 asks (it asks for
                     200 Hz; the ground truth is only logged, and packing it every frame cost ~9 %
                     of our time per frame and PX4 a parse per frame)
    boot_wait_s      [s wall] wait per frame for PX4's first actuator answer
    answer_timeout_s [s wall] once in lockstep: PX4 is given up after this long silent
    gps_eph_m, gps_epv_m, satellites   what HIL_GPS claims
    time_offset_us   PX4's clock = sim time + this [µs] (PX4 reads a time of 0 as "never")
    noise            white sensor noise
    mag_ned_gauss    Earth field at home, NED [gauss]; None: WMM2025 at home
    """

    rate_hz: int = 250
    mag_every: int = 2
    baro_every: int = 5
    gps_every: int = 25
    truth_every: int = 5
    truth_max_hz: float = 50.0
    boot_wait_s: float = 0.004
    answer_timeout_s: float = 20.0
    gps_eph_m: float = 0.3
    gps_epv_m: float = 0.4
    satellites: int = 10
    time_offset_us: int = 1_000_000
    noise: SensorNoise = field(default_factory=SensorNoise)
    mag_ned_gauss: tuple[float, float, float] | None = None

    def __post_init__(self) -> None:
        if not (250 <= self.rate_hz <= 2000) or 1_000_000 % self.rate_hz:
            raise ValueError(f"rate_hz {self.rate_hz}: need 250..2000 Hz dividing 1 s in µs")
        for k in (self.mag_every, self.baro_every, self.gps_every, self.truth_every):
            if not (isinstance(k, int) and k >= 1):
                raise ValueError("the *_every settings must be whole numbers >= 1")
        if not self.truth_max_hz > 0:
            raise ValueError(f"truth_max_hz must be > 0, got {self.truth_max_hz}")
        if not (self.boot_wait_s > 0 and self.answer_timeout_s > 0):
            raise ValueError("boot_wait_s and answer_timeout_s must be > 0")


@dataclass
class Px4Stats:
    frames: int = 0  # physics steps
    answered: int = 0  # steps made on PX4's answer (lockstep)
    unanswered_boot: int = 0  # steps made before PX4's first answer (motors off)
    stale_answers: int = 0  # actuator messages older than the frame in flight (ignored)
    dropped_bytes: int = 0


@dataclass
class Px4SimBridge:
    """skyherd's quadrotor as PX4's simulator for one PX4 SITL instance.

    `listen()` opens TCP 127.0.0.1:4560+instance, `accept()` waits for PX4, `step_once()`
    makes one lockstep frame, `serve()` loops; `state` is the true VehicleState.
    speedup: 0 = as fast as PX4 answers, 1 = real time, k = k × real time.
    """

    airframe: str = "quadrotor"
    instance: int = 0
    seed: int = 0
    home: Home = DEFAULT_HOME
    config: Px4BridgeConfig = field(default_factory=Px4BridgeConfig)
    speedup: float = 0.0
    quad_params: QuadrotorParams | None = None
    host: str = "127.0.0.1"
    stats: Px4Stats = field(default_factory=Px4Stats, init=False)

    def __post_init__(self) -> None:
        if self.airframe != "quadrotor":
            raise ValueError(
                f"airframe {self.airframe!r}: the PX4 bridge flies 'quadrotor' (none_iris)"
            )
        self.port = px4_sim_port(self.instance)
        self.body = QuadBody(self.quad_params)
        c = self.config
        mag = c.mag_ned_gauss if c.mag_ned_gauss is not None else MagField.wmm(self.home).ned_gauss
        self.mag_ned = tuple(float(v) for v in mag)
        self._noise = NoiseBlock(c.noise, self.seed)
        self._pacer = Pacer(self.speedup)
        self._framer = wire.Framer()
        self._parser = wire.FrameParser()
        self.dt_us = 1_000_000 // c.rate_hz
        self.time_us = 0
        self._k = 0  # frame index
        self._pending_us: int | None = None  # the HIL_SENSOR time awaiting PX4's answer
        self._lockstep = False
        self._controls = [0.0] * 4
        self.truth_interval_us: int | None = None  # PX4's SET_MESSAGE_INTERVAL request
        self.px4_armed = False
        self._listener: socket.socket | None = None
        self._conn: socket.socket | None = None

    # ---- connection -----------------------------------------------------------------------
    def listen(self) -> Px4SimBridge:
        if self._listener is None:
            self._listener = bind_socket(socket.SOCK_STREAM, self.host, self.port, self.instance)
        return self

    def open_port(self) -> Px4SimBridge:
        """The common bridge API's name for `listen` (see hil/bridge_select.py)."""
        return self.listen()

    def accept(self, timeout_s: float | None = None) -> bool:
        """Wait (wall time) for PX4 to connect; True once connected."""
        self.listen()
        self._listener.settimeout(timeout_s)
        try:
            conn, _ = self._listener.accept()
        except TimeoutError:
            return False
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn.setblocking(True)
        self._conn = conn
        return True

    def close(self) -> None:
        for s in (self._conn, self._listener):
            if s is not None:
                s.close()
        self._conn = self._listener = None

    def __enter__(self) -> Px4SimBridge:
        return self.listen()

    def __exit__(self, *exc) -> None:
        self.close()

    # ---- state ----------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self.time_us * 1e-6

    @property
    def state(self) -> VehicleState:
        return self.body.state()

    @property
    def in_lockstep(self) -> bool:
        return self._lockstep

    # ---- outgoing frames ------------------------------------------------------------------
    def sensor_frames(self) -> bytes:
        """HIL_SENSOR (+ HIL_GPS, HIL_STATE_QUATERNION when due) for the present state."""
        o = self.body.out.tolist()
        c, k = self.config, self._k
        t_us = self.time_us + c.time_offset_us
        nz = self._noise.next_row()
        quat = o[O_QUAT : O_QUAT + 4]
        fields = wire.FIELDS_ACCEL | wire.FIELDS_GYRO
        mx = my = mz = 0.0
        if k % c.mag_every == 0:
            fields |= wire.FIELDS_MAG
            mx, my, mz = body_from_ned(quat, self.mag_ned)
            mx, my, mz = mx + nz[6], my + nz[7], mz + nz[8]
        alt = self.home.alt_m - o[O_POS + 2]
        p_hpa = t_c = alt_b = 0.0
        if k % c.baro_every == 0:
            fields |= wire.FIELDS_BARO
            p_hpa = (isa_pressure_pa(alt) + nz[9]) * 0.01
            t_c = isa_temperature_c(alt)
            alt_b = alt + nz[9] * 0.0833  # ≈ dh/dp near sea level [m/Pa]
        payload = wire.HIL_SENSOR.pack(
            t_us,
            o[O_ACCEL] + nz[0],
            o[O_ACCEL + 1] + nz[1],
            o[O_ACCEL + 2] + nz[2],
            o[O_GYRO] + nz[3],
            o[O_GYRO + 1] + nz[4],
            o[O_GYRO + 2] + nz[5],
            mx,
            my,
            mz,
            p_hpa,
            0.0,
            alt_b,
            t_c,
            fields,
            0,
        )
        out = self._framer.frame(wire.HIL_SENSOR_ID, wire.HIL_SENSOR_CRC, payload)
        if k % c.gps_every == 0:
            out += self._gps_frame(o, nz)
        truth_every = c.truth_every
        if self.truth_interval_us:
            truth_every = max(1, round(self.truth_interval_us / self.dt_us),
                              math.ceil(c.rate_hz / c.truth_max_hz - 1e-9))  # fmt: skip
        if k % truth_every == 0:
            out += self._truth_frame(o)
        return out

    def _gps_frame(self, o: list[float], nz: list[float]) -> bytes:
        c = self.config
        pos = [o[O_POS] + nz[10], o[O_POS + 1] + nz[11], o[O_POS + 2] + nz[12]]
        lat, lon, alt = ned_to_geodetic(self.home, pos)
        vn, ve, vd = o[O_VEL] + nz[13], o[O_VEL + 1] + nz[14], o[O_VEL + 2] + nz[15]
        speed = math.hypot(vn, ve)
        cog = round(math.degrees(math.atan2(ve, vn)) * 100) % 36000 if speed > 0.05 else 65535
        payload = wire.HIL_GPS.pack(
            UTC_EPOCH_US + self.time_us,
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000),
            round(c.gps_eph_m * 100),
            round(c.gps_epv_m * 100),
            min(65534, round(speed * 100)),
            _i16(vn * 100),
            _i16(ve * 100),
            _i16(vd * 100),
            cog,
            3,
            c.satellites,
            0,
            0,
        )
        return self._framer.frame(wire.HIL_GPS_ID, wire.HIL_GPS_CRC, payload)

    def _truth_frame(self, o: list[float]) -> bytes:
        lat, lon, alt = ned_to_geodetic(self.home, o[O_POS : O_POS + 3])
        q = o[O_QUAT : O_QUAT + 4]
        ax, ay, az = (v / 9.80665 * 1000 for v in o[O_ACCEL : O_ACCEL + 3])  # [mG]
        payload = wire.HIL_STATE_Q.pack(
            self.time_us + self.config.time_offset_us,
            *q,
            o[O_GYRO],
            o[O_GYRO + 1],
            o[O_GYRO + 2],
            round(lat * 1e7),
            round(lon * 1e7),
            round(alt * 1000),
            _i16(o[O_VEL] * 100),
            _i16(o[O_VEL + 1] * 100),
            _i16(o[O_VEL + 2] * 100),
            0,
            0,
            _i16(ax),
            _i16(ay),
            _i16(az),
        )
        return self._framer.frame(wire.HIL_STATE_Q_ID, wire.HIL_STATE_Q_CRC, payload)

    # ---- incoming frames ------------------------------------------------------------------
    def _read(self, timeout_s: float) -> bool:
        """Read what PX4 sent within timeout_s; True if the pending frame got its answer."""
        conn = self._conn
        ready, _, _ = select.select([conn], [], [], timeout_s)
        if not ready:
            return False
        data = conn.recv(65536)
        if not data:
            raise ConnectionError("PX4 closed the simulator connection")
        answered = False
        for f in self._parser.feed(data):
            if f.msgid == wire.HIL_ACT_ID:
                vals = wire.HIL_ACT.unpack(f.payload)
                t_us, mode = vals[0], vals[18]
                self.px4_armed = bool(mode & 128)
                if answered or self._pending_us is None or t_us < self._pending_us:
                    self.stats.stale_answers += 1
                    continue
                self._controls = list(vals[2:6])
                answered = True
            elif f.msgid == wire.COMMAND_LONG_ID:
                vals = wire.COMMAND_LONG.unpack(f.payload)
                if (
                    vals[7] == wire.MAV_CMD_SET_MESSAGE_INTERVAL
                    and round(vals[0]) == wire.HIL_STATE_Q_ID
                ):
                    self.truth_interval_us = int(vals[1]) if vals[1] > 0 else None
        self.stats.dropped_bytes = self._parser.dropped
        return answered

    # ---- stepping -------------------------------------------------------------------------
    def step_once(self, timeout_s: float | None = None) -> bool:
        """One frame: send sensors (once), wait for PX4's answer, step. False: no answer yet.

        timeout_s bounds the wait (wall) for an answer in lockstep; None uses
        config.answer_timeout_s and raises Px4Timeout when it passes.
        """
        if self._conn is None:
            raise ConnectionError("PX4 is not connected: call accept() first")
        if self._pending_us is None:
            self._conn.sendall(self.sensor_frames())
            self._pending_us = self.time_us + self.config.time_offset_us
        if self._lockstep:
            wait = self.config.answer_timeout_s if timeout_s is None else timeout_s
            t_end = time.monotonic() + wait
            while not self._read(max(0.0, t_end - time.monotonic())):
                if time.monotonic() >= t_end:
                    if timeout_s is None:
                        raise Px4Timeout(
                            f"PX4 sent no HIL_ACTUATOR_CONTROLS for t={self.t:.3f} s "
                            f"within {wait} s: it stopped or crashed"
                        )
                    return False
            self.stats.answered += 1
        else:
            t_end = time.monotonic() + self.config.boot_wait_s
            got = False
            while not got and time.monotonic() < t_end:
                got = self._read(max(0.0, t_end - time.monotonic()))
            if got:
                self._lockstep = True
                self.stats.answered += 1
            else:
                self._controls = [0.0] * 4
                self.stats.unanswered_boot += 1
        self._pending_us = None
        self.body.step(self.dt_us * 1e-6, self._controls)
        self.time_us += self.dt_us
        self.body.t = self.time_us * 1e-6
        self._k += 1
        self.stats.frames += 1
        self._pacer.wait_until(self.t)
        return True

    def serve(
        self,
        sim_duration_s: float | None = None,
        on_step: Callable[[Px4SimBridge], bool | None] | None = None,
        connect_timeout_s: float | None = None,
    ) -> Px4Stats:
        """Accept PX4 if needed and step until sim time runs out or on_step returns True."""
        if self._conn is None and not self.accept(connect_timeout_s):
            raise TimeoutError(f"PX4 did not connect to TCP {self.host}:{self.port}")
        t_end = math.inf if sim_duration_s is None else sim_duration_s
        while self.t < t_end:
            self.step_once()
            if on_step is not None and on_step(self):
                break
        return self.stats


def _i16(v: float) -> int:
    return max(-32768, min(32767, round(v)))
