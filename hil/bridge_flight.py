"""A real autopilot flying on skyherd's physics: arm, take off to 10 m, hover 30 s, land.

Starts PX4 SITL (`none_iris`, its simulator_mavlink connecting to our `Px4SimBridge`) or
ArduCopter SITL (`--model JSON`, answered by our `ArduPilotJsonBridge`), flies the mission
over MAVLink with pymavlink from inside the bridge's step callback (so every command is
sent at a known simulation time), records the true trajectory, and reports the hover
error and the real-time factor. The binaries are the caller's: skyherd builds neither.

Run it inside a network namespace with only loopback up, e.g.
    unshare -n sh -c 'ip link set lo up && exec python -m hil.bridge_flight --autopilot px4 --bin PATH'
The opt-in tests (tests/test_bridge_autopilots.py) do exactly that.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

from pymavlink import mavutil

from flight.geo import DEFAULT_HOME
from hil.ardupilot_json import ArduPilotJsonBridge
from hil.px4_sim import Px4SimBridge

MAV = mavutil.mavlink
COPTER_GUIDED, COPTER_LAND = 4, 9


@dataclass(frozen=True)
class HoverMission:
    """The flight, in simulation seconds and metres.

    takeoff_alt_m   climb to this height above home
    settle_s        after first reaching 97 % of it, before the hover window opens
    hover_s         the hover window
    tolerance_m     the hover window passes if every true position stays this close to
                    the window's mean position
    ready_timeout_s give up if the autopilot has not armed by this sim time
    total_timeout_s give up at this sim time
    sample_hz       trajectory samples kept
    """

    takeoff_alt_m: float = 10.0
    settle_s: float = 5.0
    hover_s: float = 30.0
    tolerance_m: float = 0.5
    ready_timeout_s: float = 180.0
    total_timeout_s: float = 400.0
    sample_hz: float = 10.0


@dataclass
class FlightResult:
    autopilot: str
    speedup: float
    ok: bool = False
    reason: str = ""
    sim_s: float = 0.0
    wall_s: float = 0.0
    real_time_factor: float = 0.0
    frames: int = 0
    flight_real_time_factor: float = 0.0  # from arming to the end
    bridge_stats: dict = field(default_factory=dict)
    armed_at: float | None = None
    takeoff_sent_at: float | None = None
    reached_at: float | None = None
    hover_max_dev_m: float | None = None
    hover_mean_alt_m: float | None = None
    landed_at: float | None = None
    disarmed_at: float | None = None
    events: list = field(default_factory=list)
    trajectory: list = field(default_factory=list)  # [t, n, e, d]


class MissionPilot:
    """The state machine of the mission, run every `every` physics frames."""

    def __init__(self, autopilot: str, link, mission: HoverMission, result: FlightResult):
        self.ap, self.link, self.m, self.r = autopilot, link, mission, result
        self.phase = "ready"
        self.next_try = 5.0
        self.next_hb = 0.0
        self.next_sample = 0.0
        self.hover: list = []
        self.armed = False
        self.target_sys = 1
        # PX4 climbs to MIS_TAKEOFF_ALT (default 2.5 m): arm only once it echoed ours
        self.takeoff_alt_set = autopilot != "px4"

    def event(self, t: float, text: str) -> None:
        self.r.events.append([round(t, 3), text])

    def drain(self, t: float) -> None:
        while True:
            msg = self.link.recv_match(blocking=False)
            if msg is None:
                return
            kind = msg.get_type()
            if kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                self.target_sys = msg.get_srcSystem()
                armed = bool(msg.base_mode & MAV.MAV_MODE_FLAG_SAFETY_ARMED)
                if armed != self.armed:
                    self.armed = armed
                    self.event(t, "armed" if armed else "disarmed")
                    if armed and self.r.armed_at is None:
                        self.r.armed_at = t
                        self.armed_wall = time.monotonic()
                    if not armed and self.phase in ("land", "done"):
                        self.r.disarmed_at = t
            elif kind == "COMMAND_ACK":
                self.event(t, f"ack {msg.command} result {msg.result}")
            elif kind == "PARAM_VALUE" and msg.param_id == "MIS_TAKEOFF_ALT":
                if abs(msg.param_value - self.m.takeoff_alt_m) < 1e-3 and not self.takeoff_alt_set:
                    self.takeoff_alt_set = True
                    self.event(t, f"MIS_TAKEOFF_ALT = {msg.param_value:g}")
            elif kind == "STATUSTEXT":
                self.event(t, f"text: {msg.text}")

    def cmd(self, command: int, *params: float) -> None:
        p = list(params) + [0.0] * (7 - len(params))
        self.link.mav.command_long_send(self.target_sys, 1, command, 0, *p)

    def tick(self, t: float, state) -> bool:
        """One look at the mission at sim time t; True when it is over."""
        m, r = self.m, self.r
        if t >= self.next_hb:
            self.link.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            self.next_hb = t + 1.0
        self.drain(t)
        if t >= self.next_sample:
            r.trajectory.append([round(t, 4), *(round(float(v), 4) for v in state.pos_ned)])
            self.next_sample = t + 1.0 / m.sample_hz
        alt = -float(state.pos_ned[2])
        if t > m.total_timeout_s:
            r.reason = f"timed out in phase {self.phase}"
            return True
        if self.phase == "ready":
            if self.armed:
                self.phase = "takeoff"
            elif t > m.ready_timeout_s:
                r.reason = "never armed"
                return True
            elif t >= self.next_try:
                self.next_try = t + 2.0
                if self.ap == "px4" and not self.takeoff_alt_set:
                    # a PARAM_SET sent beside the arm command was seen lost in that race (bench,
                    # SCHED_FIFO: the climb stopped at the default 2.5 m): set, confirm, then arm
                    self.link.mav.param_set_send(
                        self.target_sys,
                        1,
                        b"MIS_TAKEOFF_ALT",
                        m.takeoff_alt_m,
                        MAV.MAV_PARAM_TYPE_REAL32,
                    )
                    self.next_try = t + 0.5
                    return False
                if self.ap != "px4":
                    self.link.mav.request_data_stream_send(
                        self.target_sys, 1, MAV.MAV_DATA_STREAM_ALL, 4, 1
                    )
                    self.link.set_mode(COPTER_GUIDED)
                self.cmd(MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1)
        if self.phase == "takeoff":
            if self.ap == "px4":
                self.cmd(MAV.MAV_CMD_NAV_TAKEOFF, -1, 0, 0, math.nan, math.nan, math.nan, math.nan)
            else:
                self.cmd(MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, m.takeoff_alt_m)
            r.takeoff_sent_at = t
            self.phase = "climb"
        elif self.phase == "climb":
            if alt >= 0.97 * m.takeoff_alt_m:
                r.reached_at = t
                self.phase = "settle"
            elif not self.armed and t - r.takeoff_sent_at > 5.0:
                r.reason = "disarmed before reaching the takeoff altitude"
                return True
            elif t - r.takeoff_sent_at > 60.0:
                r.reason = f"climb stalled at {alt:.2f} m"
                return True
        elif self.phase == "settle":
            if t >= r.reached_at + m.settle_s:
                self.phase = "hover"
                self.hover_t0 = t
        elif self.phase == "hover":
            self.hover.append([float(v) for v in state.pos_ned])
            if t >= self.hover_t0 + m.hover_s:
                n = len(self.hover)
                mean = [sum(p[k] for p in self.hover) / n for k in range(3)]
                dev = max(math.dist(p, mean) for p in self.hover)
                r.hover_max_dev_m = round(dev, 4)
                r.hover_mean_alt_m = round(-mean[2], 4)
                self.event(t, f"hover done: max deviation {dev:.3f} m at {-mean[2]:.2f} m")
                if self.ap == "px4":
                    self.cmd(MAV.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, math.nan, math.nan, math.nan)
                else:
                    self.link.set_mode(COPTER_LAND)
                self.phase = "land"
        elif self.phase == "land":
            if state.on_ground and r.landed_at is None:
                r.landed_at = t
                self.event(t, "touched down")
            if r.landed_at is not None and not self.armed:
                r.ok = r.hover_max_dev_m is not None and r.hover_max_dev_m <= m.tolerance_m
                r.reason = "flown" if r.ok else f"hover deviation {r.hover_max_dev_m} m"
                return True
            if r.landed_at is not None and t > r.landed_at + 30.0:
                r.reason = "landed but not disarmed within 30 s"
                return True
        return False


def _px4_process(px4_bin: Path, instance: int, workdir: Path, log) -> subprocess.Popen:
    """PX4 SITL with none_iris: its simulator_mavlink connects to TCP 4560+instance."""
    build = px4_bin.resolve().parent.parent  # .../build/px4_sitl_default
    env = dict(os.environ, PX4_SIM_MODEL="none_iris", PX4_SYS_AUTOSTART="10016")
    cmd = [str(px4_bin), "-d", "-i", str(instance), "-w", str(workdir), str(build / "etc")]
    return subprocess.Popen(
        cmd,
        cwd=workdir,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )


SERIAL0_STREAMS = ("RAW_SENS", "EXT_STAT", "RC_CHAN", "RAW_CTRL", "POSITION", "EXTRA1", "EXTRA2",
                   "EXTRA3", "PARAMS", "ADSB")  # fmt: skip


@dataclass(frozen=True)
class CopterRates:
    """ArduCopter's physics frame rate (SIM_RATE_HZ: one JSON frame each) and its main loop
    (SCHED_LOOP_RATE) [Hz]. It arms only with the loop at most about 0.55 of the frame rate
    (400 → 222 seen); fewer frames per simulated second is what the lockstep's speed scales with."""

    sim_rate_hz: int = 400
    loop_rate_hz: int = 200


def _copter_process(
    bin_path: Path, instance: int, speedup: float, workdir: Path, defaults: list[Path], log,
    rates: CopterRates = CopterRates(),
) -> subprocess.Popen:  # fmt: skip
    extra = workdir / "skyherd-json.parm"
    extra.write_text(
        f"FRAME_CLASS 1\nFRAME_TYPE 1\nSIM_RATE_HZ {rates.sim_rate_hz}\n"
        f"SCHED_LOOP_RATE {rates.loop_rate_hz}\n"
        "MOT_THST_HOVER 0.46\nMOT_PWM_MIN 1000\nMOT_PWM_MAX 2000\n"
        # the hover pilot reads only HEARTBEAT, COMMAND_ACK and STATUSTEXT (sent unasked):
        # no telemetry streams on SERIAL0 (parsing them was half of our CPU per frame)
        + "".join(f"SR0_{s} 0\n" for s in SERIAL0_STREAMS)
    )
    h = DEFAULT_HOME
    cmd = [
        str(bin_path),
        "--model",
        "JSON:127.0.0.1",
        "--speedup",
        str(speedup if speedup > 0 else 1000),
        "-I",
        str(instance),
        "--home",
        f"{h.lat_deg},{h.lon_deg},{h.alt_m},0",
        "--defaults",
        ",".join(str(p) for p in [*defaults, extra]),
        "-w",
    ]
    return subprocess.Popen(
        cmd,
        cwd=workdir,
        stdout=log,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )


def _connect_tcp(port: int, timeout_s: float):
    """pymavlink over TCP to 127.0.0.1:port, retried for timeout_s of wall time."""
    t_end = time.monotonic() + timeout_s
    while time.monotonic() < t_end:
        try:
            return mavutil.mavlink_connection(
                f"tcp:127.0.0.1:{port}", source_system=255, source_component=190, retries=0
            )
        except OSError:
            time.sleep(0.2)
    return None


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)  # ArduCopter ignores SIGTERM once its physics is gone
    proc.wait(10)


def fly(
    autopilot: str,
    bin_path: Path,
    instance: int,
    speedup: float,
    mission: HoverMission | None = None,
    workdir: Path | None = None,
    copter_defaults: list[Path] | None = None,
    copter_rates: CopterRates = CopterRates(),
) -> FlightResult:
    """Fly the hover mission on `autopilot` ("px4" | "arducopter") and return the result."""
    mission = mission or HoverMission()
    res = FlightResult(autopilot, speedup)
    work = Path(workdir or tempfile.mkdtemp(prefix=f"skyherd-{autopilot}-"))
    work.mkdir(parents=True, exist_ok=True)
    log = open(work / "autopilot.log", "wb")
    t0 = time.monotonic()
    proc = None
    try:
        if autopilot == "px4":
            bridge = Px4SimBridge(instance=instance, speedup=speedup).listen()
            proc = _px4_process(bin_path, instance, work, log)
            if not bridge.accept(60.0):
                res.reason = "PX4 did not connect to the simulator port"
                return res
            link = mavutil.mavlink_connection(
                f"udpout:127.0.0.1:{14280 + instance}", source_system=255, source_component=190
            )
            every = 25
        else:
            bridge = ArduPilotJsonBridge(instance=instance).open()
            proc = _copter_process(bin_path, instance, speedup, work, copter_defaults or [], log,
                                   copter_rates)  # fmt: skip
            link = _connect_tcp(5760 + 10 * instance, 60.0)  # SITL waits for this before flying
            if link is None:
                res.reason = "ArduCopter's MAVLink TCP port never accepted"
                return res
            every = 8
        pilot = None
        k = 0

        def on_step(b) -> bool:
            nonlocal k, pilot, link
            k += 1
            if k % every:
                return False
            if pilot is None:
                pilot = MissionPilot(autopilot, link, mission, res)
            return pilot.tick(b.t, b.state)

        try:
            if autopilot == "px4":
                bridge.serve(on_step=on_step)
            else:
                bridge.serve(on_step=on_step, idle_timeout_s=30.0)
                if pilot is None or not res.reason:
                    res.reason = res.reason or "ArduCopter stopped sending servo packets"
        except (TimeoutError, ConnectionError) as e:
            res.reason = f"{type(e).__name__}: {e}"
        res.sim_s = round(bridge.t, 3)
        res.frames = bridge.stats.frames
        res.bridge_stats = asdict(bridge.stats)
        if pilot is not None and res.armed_at is not None:
            wall = time.monotonic() - pilot.armed_wall
            res.flight_real_time_factor = round((bridge.t - res.armed_at) / wall, 2)
    finally:
        res.wall_s = round(time.monotonic() - t0, 3)
        res.real_time_factor = round(res.sim_s / res.wall_s, 2) if res.wall_s > 0 else 0.0
        if proc is not None:
            _stop(proc)  # the autopilot first: then its physics
        log.close()
    return res


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m hil.bridge_flight",
        description="Fly a real PX4 / ArduCopter SITL on skyherd's physics: take off, hover, land.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    ap.add_argument("--autopilot", choices=("px4", "arducopter"), required=True)
    ap.add_argument("--bin", type=Path, required=True, help="path of bin/px4 or arducopter")
    ap.add_argument("--instance", type=int, default=75)
    ap.add_argument("--speedup", type=float, default=0.0, help="0 = as fast as possible")
    ap.add_argument(
        "--defaults",
        type=Path,
        action="append",
        default=[],
        help="ArduCopter parameter file (repeatable)",
    )
    d = CopterRates()
    ap.add_argument("--sim-rate-hz", type=int, default=d.sim_rate_hz,
                    help="ArduCopter's physics frame rate (SIM_RATE_HZ) [Hz]")  # fmt: skip
    ap.add_argument("--loop-rate-hz", type=int, default=d.loop_rate_hz,
                    help="ArduCopter's main loop (SCHED_LOOP_RATE) [Hz]")  # fmt: skip
    ap.add_argument("--workdir", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=None, help="write the result as JSON here")
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="run the bridge and the autopilot (it inherits it) at SCHED_FIFO priority 1: every "
        "frame is two hand-offs between the processes, and on a loaded machine each waits for a "
        "time slice (measured 2-4x faster; needs CAP_SYS_NICE)",
    )
    args = ap.parse_args(argv)
    if not args.bin.is_file():
        print(f"error: no autopilot binary at {args.bin}", file=sys.stderr)
        return 2
    if args.realtime:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(1))
        except (PermissionError, AttributeError) as e:
            print(
                f"error: --realtime needs SCHED_FIFO (root or CAP_SYS_NICE): {e}", file=sys.stderr
            )
            return 2
    res = fly(
        args.autopilot,
        args.bin,
        args.instance,
        args.speedup,
        workdir=args.workdir,
        copter_defaults=args.defaults,
        copter_rates=CopterRates(args.sim_rate_hz, args.loop_rate_hz),
    )
    text = json.dumps(asdict(res))
    if args.out:
        args.out.write_text(text)
    summary = {k: v for k, v in asdict(res).items() if k not in ("trajectory", "events")}
    print(json.dumps(summary))
    return 0 if res.ok else 1


if __name__ == "__main__":
    sys.exit(main())
