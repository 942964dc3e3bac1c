"""Speed of skyherd's simulator bridges against a plain numpy + json / pymavlink baseline.

Prints, in one run:
In-process figures are per CPU second of this process (time.process_time), so they do not
depend on how loaded the machine is; the socket figures are wall-clock and do.

1. JSON backend, in process: frames/s of `ArduPilotJsonBridge.handle` (numba body, one
   precompiled format string) vs a plain numpy + json.dumps quadrotor answering the same
   packets (the 2-4× real-time kind of model), and both as real-time factors at 400 Hz.
2. JSON backend over real UDP: a SIM_JSON-like scripted peer in another process doing
   lockstep frames against each (frames/s, real-time factor at 400 Hz).
3. PX4 interface, in process: frames/s of one lockstep frame (sensor frames packed,
   the actuator frame parsed, physics stepped) vs the same with pymavlink doing the
   MAVLink, and as real-time factors at 250 Hz.
4. With SKYHERD_PX4_BIN / SKYHERD_ARDUCOPTER_BIN set (and run inside `unshare -n` with lo
   up): the real autopilot on the bridge, as fast as possible, for 60 s of simulated time on
   the ground (booting, its estimator converging; no client flies it): the lockstep's
   real-time factor and each side's CPU. ArduCopter is also flown on its own physics
   (`--model +`, the same binary and parameters), alternated for `--rounds` rounds with the
   bridge as the product runs it (`--pin-cpu auto`: the lockstep thread and ArduCopter on one
   CPU, runio.pin) and unpinned (`--pin-cpu off`: where the OS puts them), and the ratio of the
   real-time factors is printed against the target 0.5 (issue 31 item 4). Flights are the opt-in tests' job (tests/e2e/test_bridge_autopilots.py:
   `skyherd fly --connect` on the bridge). SKYHERD_ARDUPILOT_DEFAULTS: a folder with
   copter.parm (default: the binary's source tree). Instances 86 and 87.

    .venv/bin/python bench/bench_bridges.py [--frames N] [--rounds N] [--only-autopilots]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import common as mavlink
from tqdm import tqdm

from skyherd.flight.quadrotor import QuadrotorParams
from skyherd.hil import bridge_mavlink as wire
from skyherd.hil.ardupilot_json import ArduPilotJsonBridge
from skyherd.hil.autopilot_sitl import CopterRates
from skyherd.hil.px4_sim import Px4BridgeConfig, Px4SimBridge

SERVO = struct.Struct("<HHI16H")


class NumpyJsonQuad:
    """The baseline: the same quadrotor equations written the plain numpy way, json.dumps out."""

    def __init__(self, p: QuadrotorParams):
        self.p = p
        a = p.arm_length / math.sqrt(2.0)
        self.r = np.array([[a, a, 0], [-a, -a, 0], [a, -a, 0], [-a, a, 0]], dtype=float)
        self.spin = np.array(p.spin)
        self.inertia = np.diag(p.inertia)
        self.inv_i = np.linalg.inv(self.inertia)
        self.pos, self.vel, self.w = np.zeros(3), np.zeros(3), np.zeros(3)
        self.q = np.array([1.0, 0, 0, 0])
        self.motor = np.zeros(4)
        self.t = 0.0

    def dcm(self) -> np.ndarray:
        w, x, y, z = self.q
        return np.array(
            [
                [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
            ]
        )

    def step(self, dt: float, u: np.ndarray) -> dict:
        p = self.p
        n = max(1, math.ceil(dt / p.physics_dt - 1e-9))
        h = dt / n
        for _ in range(n):
            self.motor += (np.clip(u, 0, 1) * p.omega_max - self.motor) * (
                1 - math.exp(-h / p.time_constant)
            )
            thrust = p.k_thrust * self.motor**2
            torque = np.cross(self.r, np.array([[0, 0, -t] for t in thrust])).sum(axis=0)
            torque[2] += (self.spin * p.k_torque * self.motor**2).sum()
            r = self.dcm()
            vb = r.T @ self.vel
            f_b = -np.array(p.drag_linear) * vb - np.array(p.drag_quadratic) * np.abs(vb) * vb
            f_b[2] -= thrust.sum()
            acc = r @ f_b / p.mass + np.array([0, 0, p.gravity])
            self.spec = f_b / p.mass
            self.vel = self.vel + acc * h
            self.pos = self.pos + self.vel * h
            if self.pos[2] > 0:
                self.pos[2], self.vel[:] = 0.0, 0.0
                self.spec = np.array([0, 0, -p.gravity])
            dw = self.inv_i @ (torque - np.cross(self.w, self.inertia @ self.w))
            self.w = self.w + dw * h
            wx, wy, wz = self.w * h * 0.5
            dq = np.array([1.0, wx, wy, wz])
            w0, x0, y0, z0 = self.q
            self.q = np.array(
                [
                    w0 * dq[0] - x0 * dq[1] - y0 * dq[2] - z0 * dq[3],
                    w0 * dq[1] + x0 * dq[0] + y0 * dq[3] - z0 * dq[2],
                    w0 * dq[2] - x0 * dq[3] + y0 * dq[0] + z0 * dq[1],
                    w0 * dq[3] + x0 * dq[2] - y0 * dq[1] + z0 * dq[0],
                ]
            )
            self.q /= np.linalg.norm(self.q)
        self.t += dt
        return {
            "timestamp": self.t,
            "imu": {"gyro": self.w.tolist(), "accel_body": self.spec.tolist()},
            "position": self.pos.tolist(),
            "quaternion": self.q.tolist(),
            "velocity": self.vel.tolist(),
        }

    def handle(self, data: bytes) -> bytes:
        magic, rate, fc, *pwm = SERVO.unpack(data)
        u = (np.array(pwm[:4], dtype=float) - 1000.0) / 1000.0
        return ("\n" + json.dumps(self.step(1.0 / rate, u), separators=(",", ":")) + "\n").encode()


def packets(n: int) -> list[bytes]:
    return [SERVO.pack(18458, 400, k, *([1700] * 4 + [0] * 12)) for k in range(n)]


def bench_json_inprocess(n: int) -> tuple[float, float]:
    pk = packets(n)
    b = ArduPilotJsonBridge(instance=75)
    for k in range(50):  # warm-up (numba)
        b._rx[:40] = np.frombuffer(pk[k], dtype=np.uint8)
        b.handle(40, 0.0)
    b.reset()
    t0 = time.process_time()
    for p in pk:
        b._rx[:40] = np.frombuffer(p, dtype=np.uint8)
        b.handle(40, 0.0)
    ours = n / (time.process_time() - t0)
    base = NumpyJsonQuad(QuadrotorParams())
    m = max(200, n // 10)
    t0 = time.process_time()
    for p in pk[:m]:
        base.handle(p)
    return ours, m / (time.process_time() - t0)


_PEER = r"""
import socket, struct, sys, time
port, n = int(sys.argv[1]), int(sys.argv[2])
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.settimeout(5.0)
S = struct.Struct("<HHI16H")
t0 = time.perf_counter()
for k in range(n):
    s.sendto(S.pack(18458, 400, k, 1700, 1700, 1700, 1700, *([0] * 12)), ("127.0.0.1", port))
    s.recv(65000)
print(n / (time.perf_counter() - t0))
"""


def _serve_baseline(port: int, n: int) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", port))
    s.settimeout(10.0)
    q = NumpyJsonQuad(QuadrotorParams())
    for _ in range(n):
        data, addr = s.recvfrom(256)
        s.sendto(q.handle(data), addr)
    s.close()


def bench_json_udp(n: int) -> tuple[float, float]:
    rates = []
    for which, instance in (("ours", 76), ("baseline", 77)):
        m = n if which == "ours" else max(200, n // 10)
        port = 9002 + 10 * instance
        if which == "ours":
            b = ArduPilotJsonBridge(instance=instance).open()
            peer = subprocess.Popen(
                [sys.executable, "-c", _PEER, str(port), str(m)], stdout=subprocess.PIPE, text=True
            )
            b.serve(max_frames=m, idle_timeout_s=10.0)
            b.close()
        else:
            peer = subprocess.Popen(
                [sys.executable, "-c", _PEER, str(port), str(m)], stdout=subprocess.PIPE, text=True
            )
            _serve_baseline(port, m)
        rates.append(float(peer.communicate(timeout=60)[0]))
    return rates[0], rates[1]


def bench_px4_inprocess(n: int) -> tuple[float, float]:
    """One lockstep frame of work without the socket: pack sensors, parse the answer, step."""
    b = Px4SimBridge(instance=75, config=Px4BridgeConfig())
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    answers = [
        mav.hil_actuator_controls_encode(k * 4000, [0.7] * 16, 129, 1).pack(mav) for k in range(n)
    ]
    b._lockstep = True

    def ours(k: int) -> None:
        b.sensor_frames()
        for f in b._parser.feed(answers[k]):
            vals = wire.HIL_ACT.unpack(f.payload)
        b.body.step(0.004, vals[2:6])
        b.time_us += 4000
        b._k += 1

    out = mavlink.MAVLink(None, srcSystem=1, srcComponent=200)
    parse = mavlink.MAVLink(None)
    body = Px4SimBridge(instance=75).body

    def baseline(k: int) -> None:  # the same frame with pymavlink doing the MAVLink
        o = body.out
        out.hil_sensor_encode(
            k * 4000, *o[3:6], *o[0:3], 0.2, 0.05, -0.5, 950.0, 0.0, 584.0, 15.0, 0x1FFF, 0
        ).pack(out)
        if k % 25 == 0:
            out.hil_gps_encode(k * 4000, 3, 0, 0, 584000, 30, 40, 0, 0, 0, 0, 65535, 10).pack(out)
        if k % 5 == 0:
            out.hil_state_quaternion_encode(
                k * 4000, o[9:13], *o[0:3], 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, -1000
            ).pack(out)
        m = parse.parse_buffer(answers[k])
        body.step(0.004, m[0].controls[:4])

    res = []
    for fn, m in ((ours, n), (baseline, n)):
        for k in range(20):
            fn(k)
        t0 = time.process_time()
        for k in range(20, m):
            fn(k)
        res.append((m - 20) / (time.process_time() - t0))
    return res[0], res[1]


_PX4_PEER = r"""
import socket, sys, time
from skyherd.hil import bridge_mavlink as wire
port, n = int(sys.argv[1]), int(sys.argv[2])
for _ in range(500):
    try:
        s = socket.create_connection(("127.0.0.1", port)); break
    except OSError:
        time.sleep(0.01)
s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
fr, pa = wire.Framer(1, 1), wire.FrameParser()
done, t0 = 0, time.perf_counter()
while done < n:
    for f in pa.feed(s.recv(65536)):
        if f.msgid == wire.HIL_SENSOR_ID:
            t_us = wire.HIL_SENSOR.unpack(f.payload)[0]
            s.sendall(fr.frame(wire.HIL_ACT_ID, wire.HIL_ACT_CRC, wire.HIL_ACT.pack(t_us, 1, *([0.7] * 16), 129)))
            done += 1
print(n / (time.perf_counter() - t0))
"""


def bench_px4_tcp(n: int) -> float:
    """Frames/s of the PX4 bridge over real TCP against a PX4-like peer in another process."""
    b = Px4SimBridge(instance=78, config=Px4BridgeConfig(boot_wait_s=5.0)).listen()
    peer = subprocess.Popen(
        [sys.executable, "-c", _PX4_PEER, str(b.port), str(n)], stdout=subprocess.PIPE, text=True
    )
    b.accept(30.0)
    for _ in range(n):
        b.step_once()
    b.close()
    return float(peer.communicate(timeout=60)[0])


def _cpu_s(who: int) -> float:
    r = resource.getrusage(who)
    return r.ru_utime + r.ru_stime


def _proc_cpu_s(pid: int) -> float:
    """utime + stime [s] of a running process (/proc, clock-tick resolution)."""
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


STEADY_FROM_S = 5.0  # simulated seconds of boot left out of the steady-state figures


class _Run:
    """One autopilot process measured: its folder and log, its SERIAL0 link, and the wall
    time and CPU of both sides at launch, at STEADY_FROM_S simulated and at the end."""

    def __init__(self, name: str) -> None:
        import tempfile

        self.work = Path(tempfile.mkdtemp(prefix=f"skyherd-bench-{name}-"))
        self.log = open(self.work / "autopilot.log", "wb")
        self.proc: subprocess.Popen | None = None
        self.link: socket.socket | None = None
        self.marks: list[tuple[float, float, float]] = []  # (wall, ours CPU, autopilot CPU)
        self.keep = True  # the folder (the autopilot's log) stays unless the run went through
        self.cpu0 = (_cpu_s(resource.RUSAGE_SELF), _cpu_s(resource.RUSAGE_CHILDREN))
        self.mark()

    def mark(self) -> None:
        theirs = _proc_cpu_s(self.proc.pid) if self.proc is not None else 0.0
        self.marks.append((time.monotonic(), _cpu_s(resource.RUSAGE_SELF), theirs))

    def stop(self) -> tuple[float, float]:
        """Stop the autopilot; the CPU seconds (ours, the autopilot's) since launch."""
        from skyherd.hil import autopilot_sitl

        if self.proc is not None:
            autopilot_sitl.stop(self.proc)
            self.proc = None
        return (_cpu_s(resource.RUSAGE_SELF) - self.cpu0[0],
                _cpu_s(resource.RUSAGE_CHILDREN) - self.cpu0[1])  # fmt: skip

    def close(self) -> None:
        import shutil

        self.stop()
        if self.link is not None:
            self.link.close()
        self.log.close()
        if not self.keep:
            shutil.rmtree(self.work, ignore_errors=True)

    def row(self, sim_s: float, ours_total: float, theirs_total: float) -> dict:
        (w0, _, _), (w1, o1, t1), (w2, o2, t2) = self.marks
        steady = sim_s - STEADY_FROM_S
        return {"sim_s": round(sim_s, 1), "wall_s": round(w2 - w0, 3),
                "rtf": round(sim_s / (w2 - w0), 2), "rtf_steady": round(steady / (w2 - w1), 2),
                "cpu_ours_s": round(ours_total, 3), "cpu_autopilot_s": round(theirs_total, 3),
                "ours_per_sim_s": round((o2 - o1) / steady, 4),
                "autopilot_per_sim_s": round((t2 - t1) / steady, 4)}  # fmt: skip


def _warm_json(bridge: ArduPilotJsonBridge) -> None:
    """One servo packet through the bridge before the autopilot starts (numba's first call
    stays out of the measurement), then back at rest with its counters at zero."""
    bridge._rx[:40] = np.frombuffer(packets(1)[0], dtype=np.uint8)
    bridge.handle(40, 0.0)
    bridge.reset()
    bridge.stats = type(bridge.stats)()


def _idle_measured(name: str, path: Path, defaults: list[Path], fifo: bool, rates=None,
                   sim_s: float = 60.0, pin: str = "auto") -> dict:  # fmt: skip
    """The autopilot on the bridge as fast as possible for `sim_s` of simulated time: its
    real-time factor and the CPU seconds of each side (ours: this process; the autopilot's:
    the child). `fifo`: this process and the autopilot (which inherits it) at SCHED_FIFO
    priority 1. `pin`: ArduCopter's lockstep pair on one CPU as `skyherd sim --pin-cpu` does
    it ("auto", the default; "off": where the OS puts them; PX4 is not pinned). Wall time
    counts from the autopilot's launch; the steady figures from STEADY_FROM_S simulated on
    (its boot left out)."""
    from skyherd.hil import autopilot_sitl
    from skyherd.hil.bridge_select import make_bridge

    instance = 86
    if fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
    bridge = make_bridge("px4" if name == "px4" else "ardupilot", instance=instance,
                         pin_cpu=pin).open_port()  # fmt: skip
    cpu = getattr(bridge, "cpu", None)
    if name != "px4":
        _warm_json(bridge)
    run = _Run(name)
    try:
        if name == "px4":
            run.proc = autopilot_sitl.start_px4(path, instance, run.work, run.log)
            if not bridge.accept(60.0):
                raise RuntimeError(f"PX4 did not connect; see {run.work}/autopilot.log")
        else:
            run.proc = autopilot_sitl.start_arducopter(path, instance, run.work, run.log, defaults,
                                                       speedup=0, rates=rates or CopterRates(),
                                                       pin_cpu=pin)  # fmt: skip
            run.link = _connect_serial0(5760 + 10 * instance)  # SITL waits for it before it runs
        for until in (STEADY_FROM_S, sim_s):
            while bridge.t < until:
                if not bridge.step_once(30.0):
                    raise RuntimeError(f"{name} stopped answering at t = {bridge.t:.1f} s; see {run.work}")  # fmt: skip
            run.mark()
        ours, theirs = run.stop()
        run.keep = False
    finally:
        bridge.close()
        run.close()
        if fifo:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    frames = bridge.stats.frames
    row = run.row(bridge.t, ours, theirs)
    row.update({"autopilot": name, "physics": "skyherd", "priority": "fifo" if fifo else "normal",
                "frames": frames, "cpu": cpu,
                "rates": "" if rates is None else f" {rates.sim_rate_hz}/{rates.loop_rate_hz} Hz",
                "us_per_frame_ours": round(1e6 * ours / max(1, frames), 1),
                "us_per_frame_autopilot": round(1e6 * theirs / max(1, frames), 1)})  # fmt: skip
    return row


def _native_measured(path: Path, defaults: list[Path], sim_s: float = 60.0) -> dict:
    """The same ArduCopter binary on its own physics (`--model +`), the same parameters (the
    defaults and skyherd's frame / rates file), as fast as possible for `sim_s` simulated:
    its simulated time is SYSTEM_TIME.time_boot_ms on SERIAL0 (asked for at 10 Hz simulated
    with SET_MESSAGE_INTERVAL); ours is the CPU of that reading."""
    from skyherd.hil import autopilot_sitl

    instance = 87
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    mav.robust_parsing = True  # SITL's SERIAL0 starts with text lines before MAVLink
    ask = mav.command_long_encode(1, 1, wire.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                  mavlink.MAVLINK_MSG_ID_SYSTEM_TIME, 100_000, 0, 0, 0, 0, 0)  # fmt: skip
    ask = ask.pack(mav)
    run = _Run("native")
    try:
        run.proc = autopilot_sitl.start_arducopter(path, instance, run.work, run.log, defaults,
                                                   speedup=0, model="+", pin_cpu="off")  # fmt: skip
        link = run.link = _connect_serial0(5760 + 10 * instance)
        link.settimeout(0.01)
        t_sim, asked, t_give_up = 0.0, 0.0, time.monotonic() + 120.0
        for until in (STEADY_FROM_S, sim_s):
            while t_sim < until:
                now = time.monotonic()
                if now > t_give_up:
                    raise RuntimeError(f"ArduCopter --model + stuck at {t_sim:.1f} s; see {run.work}")  # fmt: skip
                if t_sim == 0.0 and now - asked > 0.01:  # until SYSTEM_TIME streams
                    link.sendall(ask)
                    asked = now
                try:
                    data = link.recv(65536)
                except TimeoutError:
                    continue
                for m in mav.parse_buffer(data) or ():
                    if m.get_msgId() == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:
                        t_sim = max(t_sim, m.time_boot_ms / 1000.0)
            run.mark()
        ours, theirs = run.stop()
        run.keep = False
    finally:
        run.close()
    row = run.row(t_sim, ours, theirs)
    row.update({"autopilot": "arducopter", "physics": "native", "priority": "normal"})
    return row


def _connect_serial0(port: int, timeout_s: float = 60.0) -> socket.socket:
    """A TCP client on ArduPilot SITL's SERIAL0 (it waits for one before it runs)."""
    t_end = time.monotonic() + timeout_s
    while True:
        try:
            return socket.create_connection(("127.0.0.1", port), timeout=1.0)
        except OSError:
            if time.monotonic() > t_end:
                raise
            time.sleep(0.005)


def _print_row(row: dict) -> None:
    if row["physics"] == "native":
        what, who = "arducopter native (--model +)", "ours (SYSTEM_TIME reader)"
    else:
        where = " unpinned" if row["cpu"] is None else f" on CPU {row['cpu']}"
        what = f"{row['autopilot']}{row['rates']} JSON {row['priority']}{where}"
        who = "ours (bridge)"
        if row["autopilot"] == "px4":
            what = f"px4 {row['priority']}"
    extra = ""
    if "frames" in row:
        extra = (f"; {row['frames']} frames, per frame: ours {row['us_per_frame_ours']} us, "
                 f"the autopilot's {row['us_per_frame_autopilot']} us")  # fmt: skip
    print(f"  {what:<32} real-time factor {row['rtf']:6.2f}x from launch, {row['rtf_steady']:6.2f}x "
          f"steady ({row['sim_s']} s simulated in {row['wall_s']:.2f} s wall); CPU per simulated s "
          f"(steady): autopilot {row['autopilot_per_sim_s']:.4f} s, {who} "
          f"{row['ours_per_sim_s']:.4f} s{extra}")  # fmt: skip


def _arducopter_defaults(binary: Path) -> list[Path]:
    """copter.parm: SKYHERD_ARDUPILOT_DEFAULTS, else the binary's source tree
    (build/sitl/bin/arducopter → Tools/autotest/default_params)."""
    folder = os.environ.get("SKYHERD_ARDUPILOT_DEFAULTS")
    root = Path(folder) if folder else binary.resolve().parents[3] / "Tools/autotest/default_params"
    return [root / "copter.parm"] if (root / "copter.parm").is_file() else []


def real_autopilots(rounds: int = 3, variants: bool = False) -> list[dict]:
    """PX4 on the bridge at normal priority and (when allowed) SCHED_FIFO; ArduCopter on its
    own physics and on skyherd's JSON bridge, alternated for `rounds` rounds, and their ratio
    against the 0.5 target. `variants`: also ArduCopter at SCHED_FIFO and at 200/100 Hz."""
    out = []
    px4 = os.environ.get("SKYHERD_PX4_BIN")
    if not px4:
        print("  px4: SKYHERD_PX4_BIN not set, skipped")
    else:
        for fifo in (False, True):
            try:
                row = _idle_measured("px4", Path(px4), [], fifo)
            except PermissionError:
                print("  px4: SCHED_FIFO not permitted, skipped")
                continue
            out.append(row)
            _print_row(row)
    path = os.environ.get("SKYHERD_ARDUCOPTER_BIN")
    if not path:
        print("  arducopter: SKYHERD_ARDUCOPTER_BIN not set, skipped")
        return out
    defaults = _arducopter_defaults(Path(path))
    print(f"  arducopter defaults: {', '.join(str(d) for d in defaults) or 'none'} + skyherd's "
          f"frame and rates ({CopterRates().sim_rate_hz}/{CopterRates().loop_rate_hz} Hz)")  # fmt: skip
    print(f"  load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the start")
    pins = {"JSON pinned (default)": "auto", "JSON unpinned": "off"}
    rows: dict[str, list[dict]] = {"native": []} | {key: [] for key in pins}
    for _ in range(rounds):  # alternated: the machine's load drifts over all alike
        for key in rows:
            if key == "native":
                row = _native_measured(Path(path), defaults)
            else:
                row = _idle_measured("arducopter", Path(path), defaults, False, pin=pins[key])
            rows[key].append(row)
            out.append(row)
            _print_row(row)

    def median(key: str, field: str) -> float:
        v = sorted(r[field] for r in rows[key])
        return v[len(v) // 2]

    print(f"  load average {' '.join(f'{x:.2f}' for x in os.getloadavg())} at the end")
    for key in pins:
        for field, label in (("rtf_steady", "steady"), ("rtf", "from launch")):
            j, n = median(key, field), median("native", field)
            print(f"  {key} / native ({label}, medians of {rounds}): {j:.2f}x / {n:.2f}x = "
                  f"{j / n:.3f} (target >= 0.5: {'met' if j / n >= 0.5 else 'not met'})")  # fmt: skip
    for field in ("autopilot_per_sim_s", "ours_per_sim_s"):
        print(f"  CPU per simulated s, {field.split('_per')[0]} (medians): "
              + ", ".join(f"{key} {median(key, field):.4f} s" for key in rows))  # fmt: skip
    if variants:
        for fifo, rates in ((True, None), (False, CopterRates(200, 100))):
            try:
                row = _idle_measured("arducopter", Path(path), defaults, fifo, rates)
            except PermissionError:
                print("  arducopter: SCHED_FIFO not permitted, skipped")
                continue
            out.append(row)
            _print_row(row)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n")[0], formatter_class=argparse.ArgumentDefaultsHelpFormatter
    )
    ap.add_argument("--frames", type=int, default=20000, help="frames per measurement")
    ap.add_argument("--repeat", type=int, default=3, help="interleaved rounds (best kept)")
    ap.add_argument("--no-autopilots", action="store_true", help="skip the real-autopilot part")
    ap.add_argument("--only-autopilots", action="store_true", help="only the real-autopilot part")
    ap.add_argument("--rounds", type=int, default=3, help="ArduCopter native / JSON rounds")
    ap.add_argument("--variants", action="store_true",
                    help="also ArduCopter at SCHED_FIFO and at 200/100 Hz")  # fmt: skip
    args = ap.parse_args(argv)
    if args.only_autopilots:
        print("Real autopilots (as fast as possible, on the ground):")
        real_autopilots(args.rounds, args.variants)
        return 0
    n = args.frames
    best: dict[str, float] = {}
    for _ in tqdm(range(args.repeat), desc="rounds"):  # interleaved rounds, best of each
        for key, fn in (
            ("json", bench_json_inprocess),
            ("json_udp", bench_json_udp),
            ("px4", bench_px4_inprocess),
        ):
            ours, base = fn(n)
            best[key] = max(best.get(key, 0.0), ours)
            best[key + "_base"] = max(best.get(key + "_base", 0.0), base)
        best["px4_tcp"] = max(best.get("px4_tcp", 0.0), bench_px4_tcp(n))
    rows = [
        ("JSON backend, in process (handle one servo packet)", "json", "numpy+json", 400),
        ("JSON backend over UDP, SIM_JSON-like peer process", "json_udp", "numpy+json", 400),
        ("PX4 interface, in process (one lockstep frame)", "px4", "pymavlink", 250),
    ]
    print(f"best of {args.repeat} interleaved rounds, {n} frames each; frames/s (real-time factor)")
    print("in process: per CPU second; over sockets: per wall second (load-dependent)")
    for title, key, base_name, hz in rows:
        ours, base = best[key], best[key + "_base"]
        print(title + f" at {hz} Hz:")
        print(f"  skyherd bridge   {ours:10.0f}  ({ours / hz:6.1f}x)")
        print(f"  {base_name:<16} {base:10.0f}  ({base / hz:6.1f}x)   ratio {ours / base:5.1f}")
    tcp = best["px4_tcp"]
    print("PX4 interface over TCP, PX4-like peer process at 250 Hz:")
    print(f"  skyherd bridge   {tcp:10.0f}  ({tcp / 250:6.1f}x)")
    if not args.no_autopilots:
        print("Real autopilots (as fast as possible, on the ground):")
        real_autopilots(args.rounds, args.variants)
    return 0


if __name__ == "__main__":
    sys.exit(main())
