"""The companion's own code (mission.vehicle.VehicleLink ticked by mission.companion.run
free-running, the phases and recipes of mission.steps, mission.authority, mission.flight) against
a scripted ArduCopter / ArduPlane / PX4 (SCRIPTED PEERS, not the real firmware: ArduPilot is not
on a package registry). The peer speaks MAVLink 2 frames built by
pymavlink over a real UDP socket, byte for byte as the published protocol and as real
ArduCopter SITL answered when it was measured (../shared/PROTOCOLS.md):

- it streams nothing but HEARTBEAT and STATUSTEXT until asked (SET_MESSAGE_INTERVAL), and
  never sends ATTITUDE_QUATERNION or EXTENDED_SYS_STATE;
- its EKF uses GPS 41 s after boot: only then LOCAL_POSITION_NED and HOME_POSITION;
- the first arm is refused (COMMAND_ACK FAILED, then 100 ms later STATUSTEXT "PreArm: Gyros
  inconsistent", in two chunks); arming needs GUIDED for a take-off, NAV_TAKEOFF reads param 7
  above home and is refused unless GUIDED and armed; LOITER sinks without a pilot's throttle;
- its fence refuses targets beyond 50 m (the copter stops at the edge) with a STATUSTEXT.

The peer runs its own clock at `RATE`× wall time; the companion ticks on that clock (every
0.1 s of it) and every limit a phase waits under counts it, so the result does not depend on
the machine's load (the wall backstop: 30 s without a message). Ports: those of vehicle instances 70-74 (14610-14614), reused test after test.
"""

from __future__ import annotations

import math
import socket
import threading
import time

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.hil.autopilots import ARDUPLANE
from skyherd.hil.telemetry import reposition_command
from skyherd.mission.authority import ModeAuthority
from skyherd.mission.flight import FlightPlan, Record, SingleVehicleMission
from skyherd.mission.pilots import WaypointPilot
from skyherd.mission.steps import (
    CommandRefused,
    command,
    recipe,
    set_mode,
    wait_ready,
    wait_s,
    wait_until,
)
from tests.companion_flights import Steps, fly, watched

RATE = 8.0  # peer seconds per wall second
DT = 0.02  # peer step [s]
HOME = (-35.363261, 149.165230, 584.0)
GUIDED, LOITER, RTL, LAND, BRAKE, STABILIZE = 4, 5, 6, 9, 17, 0


class ScriptedArduCopter:
    """A scripted ArduCopter on 127.0.0.1:`port` (udpin: it answers whoever sent last)."""

    def __init__(self, port: int, ekf_after_s: float = 41.0, fence_m: float = 50.0,
                 mav_type: int = M.MAV_TYPE_QUADROTOR, legacy: bool = False):  # fmt: skip
        self.legacy = legacy  # older firmware: no SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM only
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", port))
        self.sock.setblocking(False)
        self.peer = None
        self.mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
        self.rx = M.MAVLink(None)
        self.mav_type = mav_type
        self.t = 0.0
        self.ekf_after_s, self.fence_m = ekf_after_s, fence_m
        self.mode, self.armed = STABILIZE, False
        self.pos, self.vel = np.zeros(3), np.zeros(3)
        self.target: np.ndarray | None = None
        self.takeoff_alt: float | None = None
        self.arm_attempts = 0
        self.rates: dict[int, float] = {}
        self.next_due: dict[int, float] = {}
        self.queue: list[tuple[float, object]] = []  # (peer time, message) sent later
        self.senders: set[int] = set()
        self.commands: list[tuple[float, int, tuple]] = []
        self.modes: list[tuple[float, int]] = []
        self.setpoints_after_land = 0
        self.setpoint_times: list[float] = []  # SET_POSITION_TARGET_LOCAL_NED arrivals [s]
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join(5)
        self.sock.close()

    @property
    def ekf_ok(self) -> bool:
        return self.t >= self.ekf_after_s

    def send(self, msg) -> None:
        if self.peer is not None:
            self.sock.sendto(msg.pack(self.mav), self.peer)
            self.mav.seq = (self.mav.seq + 1) % 256

    def text(self, words: str, severity=M.MAV_SEVERITY_CRITICAL, delay=0.0, chunk_id=0) -> None:
        if chunk_id == 0:
            self.queue.append(
                (self.t + delay, M.MAVLink_statustext_message(severity, words.encode()))
            )
            return
        for seq, i in enumerate(range(0, len(words) + 1, 50)):
            part = words[i : i + 50].encode()
            self.queue.append(
                (self.t + delay, M.MAVLink_statustext_message(severity, part, chunk_id, seq))
            )

    def ack(self, cmd: int, result: int) -> None:
        self.send(M.MAVLink_command_ack_message(cmd, result, 0, 0, 255, 191))

    # ---- the loop ------------------------------------------------------------------------------
    def _run(self) -> None:
        wall0 = time.monotonic()
        t_hb = -1.0
        while not self._stop.is_set():
            self._receive()
            self._step()
            if self.t - t_hb >= 1.0:
                t_hb = self.t
                base = M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (
                    M.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
                )
                state = M.MAV_STATE_ACTIVE if self.armed else M.MAV_STATE_STANDBY
                self.send(
                    M.MAVLink_heartbeat_message(
                        self.mav_type, M.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.mode, state, 3
                    )
                )
            for msg_id, hz in self.rates.items():
                if self.t >= self.next_due.get(msg_id, 0.0):
                    self.next_due[msg_id] = self.t + 1.0 / hz
                    m = self._build(msg_id)
                    if m is not None:
                        self.send(m)
            due = [q for q in self.queue if q[0] <= self.t]
            self.queue = [q for q in self.queue if q[0] > self.t]
            for _, m in due:
                self.send(m)
            self.t += DT
            lag = (wall0 + self.t / RATE) - time.monotonic()
            if lag > 0:
                time.sleep(lag)

    def _receive(self) -> None:
        while True:
            try:
                data, self.peer = self.sock.recvfrom(65535)
            except BlockingIOError:
                return
            for m in self.rx.parse_buffer(data) or []:
                self.senders.add(m.get_srcComponent())
                self._on(m)

    def _build(self, msg_id: int):
        ms = int(self.t * 1000)
        if msg_id == M.MAVLINK_MSG_ID_ATTITUDE:
            return M.MAVLink_attitude_message(ms, 0.0, 0.0, 0.1, 0.0, 0.0, 0.0)
        if msg_id == M.MAVLINK_MSG_ID_SYS_STATUS:
            pre = M.MAV_SYS_STATUS_PREARM_CHECK
            return M.MAVLink_sys_status_message(
                pre, pre, pre if self.ekf_ok else 0, 0, 12600, -1, 100, 0, 0, 0, 0, 0, 0
            )
        if msg_id == M.MAVLINK_MSG_ID_GPS_RAW_INT:
            return M.MAVLink_gps_raw_int_message(
                ms * 1000, 3 if self.t > 5 else 1, 0, 0, 0, 0, 0, 0, 0, 10
            )
        if msg_id == M.MAVLINK_MSG_ID_EKF_STATUS_REPORT:
            flags = 0x1 | 0x2 | (0x10 if self.ekf_ok else 0)
            return M.MAVLink_ekf_status_report_message(flags, 0, 0, 0, 0, 0)
        if not self.ekf_ok:
            return None  # no position before the EKF uses GPS
        if msg_id == M.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return M.MAVLink_local_position_ned_message(ms, *self.pos, *self.vel)
        if msg_id == M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            return M.MAVLink_global_position_int_message(
                ms,
                int(HOME[0] * 1e7),
                int(HOME[1] * 1e7),
                int((HOME[2] - self.pos[2]) * 1000),
                int(-self.pos[2] * 1000),
                0,
                0,
                0,
                0,
            )
        if msg_id == M.MAVLINK_MSG_ID_HOME_POSITION:
            return self._home()
        return None

    def _home(self):
        return M.MAVLink_home_position_message(
            int(HOME[0] * 1e7),
            int(HOME[1] * 1e7),
            int(HOME[2] * 1000),
            0.0,
            0.0,
            0.0,
            [1, 0, 0, 0],
            0.0,
            0.0,
            0.0,
        )

    def _on(self, m) -> None:
        t = m.get_type()
        if t == "COMMAND_LONG":
            self.commands.append((self.t, m.command, (m.param1, m.param2, m.param7)))
            self._command(m)
        elif t == "REQUEST_DATA_STREAM" and self.legacy and m.start_stop:
            groups = {M.MAV_DATA_STREAM_POSITION: (M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                                                   M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT),
                      M.MAV_DATA_STREAM_EXTRA1: (M.MAVLINK_MSG_ID_ATTITUDE,),
                      M.MAV_DATA_STREAM_EXTENDED_STATUS: (M.MAVLINK_MSG_ID_SYS_STATUS,
                                                          M.MAVLINK_MSG_ID_GPS_RAW_INT,
                                                          M.MAVLINK_MSG_ID_EKF_STATUS_REPORT)}  # fmt: skip
            for msg_id in groups.get(m.req_stream_id, ()):
                self.rates[msg_id] = float(m.req_message_rate)
        elif t == "SET_POSITION_TARGET_LOCAL_NED":
            self.setpoint_times.append(self.t)
            if self.mode == LAND and not self.armed:
                self.setpoints_after_land += 1  # still streaming when the landing ended
            if self.mode == GUIDED and self.armed and self.takeoff_alt is None:
                p = np.array([m.x, m.y, m.z])
                if np.hypot(p[0], p[1]) > self.fence_m:
                    self.text("Fence: target outside fence", M.MAV_SEVERITY_WARNING)
                    p[:2] *= (self.fence_m - 1.0) / np.hypot(p[0], p[1])
                self.target = p

    def _command(self, m) -> None:
        c = m.command
        if c == M.MAV_CMD_SET_MESSAGE_INTERVAL:
            if self.legacy:
                self.ack(c, M.MAV_RESULT_UNSUPPORTED)
                return
            self.rates[int(m.param1)] = 1e6 / m.param2
            self.ack(c, M.MAV_RESULT_ACCEPTED)
        elif c == M.MAV_CMD_REQUEST_MESSAGE:
            self.ack(c, M.MAV_RESULT_ACCEPTED)
            if int(m.param1) == M.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
                self.send(
                    M.MAVLink_autopilot_version_message(
                        0, (4 << 24) | (7 << 16), 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 77
                    )
                )
            elif int(m.param1) == M.MAVLINK_MSG_ID_HOME_POSITION and self.ekf_ok:
                self.send(self._home())
        elif c == M.MAV_CMD_DO_SET_MODE:
            self.mode = int(m.param2)
            self.modes.append((self.t, self.mode))
            self.ack(c, M.MAV_RESULT_ACCEPTED)
        elif c == M.MAV_CMD_COMPONENT_ARM_DISARM:
            self.arm_attempts += 1
            if m.param1 == 1 and (self.arm_attempts == 1 or not self.ekf_ok):
                self.ack(c, M.MAV_RESULT_FAILED)  # the reason follows ~100 ms later, chunked
                self.text(
                    "PreArm: Gyros inconsistent (the first attempt after boot is refused "
                    "while the gyros settle)",
                    delay=0.1,
                    chunk_id=7,
                )
            else:
                self.armed = m.param1 == 1
                self.ack(c, M.MAV_RESULT_ACCEPTED)
        elif c == M.MAV_CMD_NAV_TAKEOFF:
            if self.mode != GUIDED or not self.armed:
                self.ack(c, M.MAV_RESULT_FAILED)
            else:
                self.takeoff_alt = m.param7  # above home
                self.ack(c, M.MAV_RESULT_ACCEPTED)
        else:
            self.ack(c, M.MAV_RESULT_UNSUPPORTED)

    def _step(self) -> None:
        """A kinematic copter: 2.5 m/s climb, 5 m/s toward a target, LOITER sinks (no RC)."""
        if not self.armed:
            self.vel[:] = 0
            return
        v = np.zeros(3)
        if self.takeoff_alt is not None:
            v[2] = -2.5 if -self.pos[2] < self.takeoff_alt else 0.0
            if -self.pos[2] >= self.takeoff_alt:
                self.takeoff_alt, self.target = None, self.pos.copy()
        elif self.mode == GUIDED and self.target is not None:
            d = self.target - self.pos
            n = np.linalg.norm(d)
            v = d / n * min(5.0, n / DT) if n > 1e-6 else v
        elif self.mode == LOITER:
            v[2] = 2.5  # no pilot throttle: it sinks
        elif self.mode == LAND:
            v[2] = 1.0
        self.vel = v
        self.pos = self.pos + v * DT
        if self.pos[2] > 0:
            self.pos[2] = 0.0
            if self.mode == LAND:
                self.armed = False


@pytest.mark.timeout(240)
@pytest.mark.slow
def test_scripted_arducopter_flies_twice_with_guided_takeoff_and_brake_fallback():
    seen: dict = {}

    def two_missions(v):
        yield from wait_ready(v)
        seen["ready_t"] = v.t
        prof, auth = v.profile, ModeAuthority()
        target = Setpoint(pos_ned=np.array([5.0, 0.0, -10.0]))
        for mission in range(2):
            yield from recipe(v, prof.takeoff_steps(10.0, v.home_amsl_m))
            peer.setpoints_after_land = 0  # the stream before GUIDED found it landed: fine
            seen.setdefault("arm_attempts", peer.arm_attempts)
            seen.setdefault("texts", [x for _, _, x in v.tel.statustexts])
            seen[f"takeoff_{mission}"] = (-v.tel.pos_ned[2], v.tel.mode, list(peer.commands))
            yield from recipe(v, prof.handover_steps(), hold=lambda: target)
            yield from wait_until(v, lambda: np.linalg.norm(v.tel.pos_ned - target.pos_ned) < 0.5,
                                  30.0, "the target")  # fmt: skip
            # the safety net's fallback through the mapping the missions use: BRAKE, never
            # LOITER (5) — it would sink without a pilot's throttle
            auth.adopt(v, prof.ai_mode)
            auth.want(v, prof.fallback_mode)
            yield from watched(v, auth, lambda: v.tel.mode_name == "BRAKE", "BRAKE")
            seen[f"fallback_{mission}"] = peer.mode
            auth.want(v, prof.ai_mode)
            yield from watched(v, auth, lambda: v.tel.mode is prof.ai_mode, "GUIDED")
            seen[f"rule_{mission}"] = (auth.update(v), auth.yielded)
            yield from recipe(v, prof.land_steps() + prof.end_steps())
            seen[f"landed_{mission}"] = (v.tel.armed, v.setpoint, peer.setpoints_after_land)

    with ScriptedArduCopter(14610) as peer:
        v = fly("udpout:127.0.0.1:14610", Steps(), two_missions)
    assert v.profile.name == "ArduCopter"
    assert seen["ready_t"] >= 41.0  # readiness waited for the EKF by condition, past 30 s
    assert v.tel.quat is not None  # ATTITUDE (no ATTITUDE_QUATERNION from ArduPilot)
    assert 191 in peer.senders and 190 not in peer.senders
    # the first arm was refused and retried; its reason (two chunks) was read
    assert seen["arm_attempts"] == 2
    assert any(
        "Gyros inconsistent (the first" in x and x.endswith("settle)") for x in seen["texts"]
    )
    for mission in range(2):
        alt, mode, cmds = seen[f"takeoff_{mission}"]
        assert 9.4 < alt and mode is FlightMode.OFFBOARD
        kinds = [cmd for _, cmd, _ in cmds]
        # GUIDED before the arm, the take-off altitude relative to home (not 594 m AMSL)
        i_mode = max(i for i, k in enumerate(kinds) if k == M.MAV_CMD_DO_SET_MODE)
        i_arm = max(i for i, k in enumerate(kinds) if k == M.MAV_CMD_COMPONENT_ARM_DISARM)
        i_to = kinds.index(M.MAV_CMD_NAV_TAKEOFF, i_arm)
        assert i_mode < i_arm < i_to and cmds[i_to][2][2] == 10.0
        assert seen[f"fallback_{mission}"] == BRAKE
        assert seen[f"rule_{mission}"] == ("fly", None)  # every mode change was asked for
        assert seen[f"landed_{mission}"] == (False, None, 0)  # no setpoint after the landing
    assert [name for _, name in v.tel.modes].count("GUIDED") >= 2


@pytest.mark.timeout(240)
def test_scripted_arducopter_failsafe_is_yielded_to_by_the_companions_mission():
    """SingleVehicleMission (what `skyherd companion --mission square` flies): ArduCopter goes
    RTL by itself mid-flight (a battery failsafe); the mission yields — no setpoint, no mode
    request from then on — waits for the autopilot's landing, and ends "yielded"."""

    class FailsafeAfter(WaypointPilot):
        t_ai: float | None = None  # the pilot's first decision: the AI phase began

        def propose(self, o):
            self.t_ai = o.t if self.t_ai is None else self.t_ai
            if o.t - self.t_ai >= 10.0 and peer.mode != RTL:
                peer.mode, peer.t_rtl = RTL, peer.t  # the autopilot's own decision
            return super().propose(o)

    pilot = FailsafeAfter([np.array([10.0, 0.0, -10.0])], settle_s=1e9)
    plan = FlightPlan(altitude_m=10.0, duration_s=60.0, decision_s=0.5, yield_wait_s=10.0)
    mission = SingleVehicleMission(pilot, None, plan, Record())

    with ScriptedArduCopter(14611, ekf_after_s=2.0) as peer:
        peer.t_rtl = None
        fly("udpout:127.0.0.1:14611", mission)
        n_modes = sum(
            1 for t, c, _ in peer.commands if c == M.MAV_CMD_DO_SET_MODE and t > peer.t_rtl
        )
        # the companion learns of RTL from the next heartbeat (1 Hz) and stops at that tick
        late = [t for t in peer.setpoint_times if t > peer.t_rtl + 1.3]
    assert mission.outcome == "yielded" and "RTL" in mission.reason, mission.reason
    assert "still armed in RTL" in mission.reason  # the scripted copter never lands in RTL
    assert n_modes == 0 and not late and peer.mode == RTL  # never taken back


@pytest.mark.timeout(120)
def test_refused_command_carries_the_autopilots_reason_sent_after_the_ack():
    refusals = []

    def try_commands(v):
        yield from wait_ready(v)
        for cmd, params in ((M.MAV_CMD_COMPONENT_ARM_DISARM, (1, 0)),
                            (M.MAV_CMD_NAV_TAKEOFF, (0, 0, 0, math.nan, 0, 0, 10.0))):  # fmt: skip
            try:
                yield from command(v, cmd, *params)
            except CommandRefused as e:
                refusals.append(str(e))

    with ScriptedArduCopter(14612, ekf_after_s=1.0) as peer:
        fly("udpout:127.0.0.1:14612", Steps(), try_commands)
    arm, takeoff = refusals  # NAV_TAKEOFF before GUIDED + arm: refused too
    assert "COMPONENT_ARM_DISARM failed: MAV_RESULT_FAILED" in arm
    assert "PreArm: Gyros inconsistent (the first attempt" in arm and arm.endswith("settle)")
    assert "NAV_TAKEOFF failed: MAV_RESULT_FAILED" in takeoff and peer.commands[-1][2][2] == 10.0


@pytest.mark.timeout(120)
def test_scripted_arduplane_modes_decode_with_the_plane_table():
    decoded, errors = [], []

    def modes(v):
        yield from wait_ready(v)
        for number, name in ((15, "GUIDED"), (12, "LOITER"), (11, "RTL"), (5, "FBWA")):
            peer.mode = number
            yield from wait_until(v, lambda n=name: v.tel.mode_name == n, 5.0, name)
            decoded.append(v.tel.mode)
        yield from set_mode(v, FlightMode.HOLD)
        decoded.append(peer.mode)
        try:
            yield from set_mode(v, FlightMode.LAND)
        except ValueError as e:
            errors.append(str(e))

    with ScriptedArduCopter(14613, ekf_after_s=1.0, mav_type=M.MAV_TYPE_FIXED_WING) as peer:
        v = fly("udpout:127.0.0.1:14613", Steps(), modes)
    assert v.profile.name == "ArduPlane"
    assert decoded == [FlightMode.OFFBOARD, FlightMode.HOLD, FlightMode.RTL,
                       FlightMode.STABILIZED, 12]  # HOLD set as LOITER (12), not the copter's 5  # fmt: skip
    assert len(errors) == 1 and "no mode for LAND" in errors[0]
    steps = ARDUPLANE.takeoff_steps(40.0, 584.0)
    assert M.MAV_CMD_NAV_TAKEOFF not in [s.command for s in steps]
    assert [s.mode for s in steps if s.kind == "set_mode"] == [FlightMode.TAKEOFF]
    assert math.isclose(ARDUPLANE.set_mode_params(FlightMode.TAKEOFF)[1], 13)


@pytest.mark.timeout(120)
def test_older_firmware_without_set_message_interval_gets_request_data_stream():
    with ScriptedArduCopter(14614, ekf_after_s=1.0, legacy=True) as peer:
        v = fly(
            "udpout:127.0.0.1:14614", Steps(), wait_ready
        )  # home on request (REQUEST_MESSAGE), the rest streamed
    assert peer.rates[M.MAVLINK_MSG_ID_LOCAL_POSITION_NED] >= 10
    assert v.tel.pos_ned is not None and v.tel.quat is not None


PX4_AUTO, PX4_OFFBOARD = 4, 6
PX4_LOITER, PX4_TAKEOFF, PX4_LAND = 3, 2, 6
OF_LOSS_S = 4.0  # [s peer time] PX4's offboard-loss limit, 0.5 s of wall time at RATE 8
UNSUPPORTED_MAV_FRAME = (
    9  # MAV_RESULT_COMMAND_UNSUPPORTED_MAV_FRAME (common.xml, newer than this dialect)
)


class ScriptedPx4(ScriptedArduCopter):
    """A scripted PX4 (SIH) on the same kinematic copter, answering as PX4 did when measured:
    custom_mode main << 16 | sub << 24; OFFBOARD accepted only while setpoints stream; DO_SET_MODE
    answered by two ACKs; NAV_TAKEOFF param 7 AMSL; DO_REPOSITION in GLOBAL_INT frames only; a
    setpoint stream still running when it disarms after a landing puts it back in OFFBOARD, and
    the next arm is TEMPORARILY_REJECTED with "Resolve system health failures first" 124 ms
    after the ACK. It streams its telemetry without being asked."""

    def __init__(self, port: int):
        super().__init__(port, ekf_after_s=2.0, mav_type=M.MAV_TYPE_QUADROTOR)
        self.main, self.sub = PX4_AUTO, PX4_LOITER
        self.last_sp_t = -1e9
        self.rates = {M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0, M.MAVLINK_MSG_ID_ATTITUDE: 10.0,
                      M.MAVLINK_MSG_ID_HOME_POSITION: 0.5, M.MAVLINK_MSG_ID_GPS_RAW_INT: 2.0}  # fmt: skip
        self.disarmed_in_offboard = 0
        self.reposition_results: list[int] = []

    @property
    def mode(self):  # the copter model's notion: GUIDED while OFFBOARD, LAND while landing
        if self.main == PX4_OFFBOARD:
            return GUIDED
        return LAND if (self.main, self.sub) == (PX4_AUTO, PX4_LAND) else BRAKE

    @mode.setter
    def mode(self, value):
        pass  # set through main/sub

    def send(self, msg) -> None:
        if msg.get_type() == "HEARTBEAT":
            msg.autopilot = M.MAV_AUTOPILOT_PX4
            msg.custom_mode = (self.main << 16) | (self.sub << 24)
        super().send(msg)

    def _on(self, m) -> None:
        if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            self.last_sp_t = self.t
            if not self.armed and (self.main, self.sub) == (PX4_AUTO, PX4_LAND):
                self.main, self.sub = PX4_OFFBOARD, 0  # the measured PX4 behaviour
                self.disarmed_in_offboard += 1
            if self.main == PX4_OFFBOARD and self.armed and self.takeoff_alt is None:
                self.target = np.array([m.x, m.y, m.z])
            return
        if m.get_type() == "COMMAND_INT" and m.command == M.MAV_CMD_DO_REPOSITION:
            ok = m.frame in (M.MAV_FRAME_GLOBAL, M.MAV_FRAME_GLOBAL_INT)
            result = M.MAV_RESULT_ACCEPTED if ok else UNSUPPORTED_MAV_FRAME
            self.reposition_results.append(result)
            self.ack(m.command, result)
            return
        super()._on(m)

    def _command(self, m) -> None:
        c = m.command
        if c == M.MAV_CMD_DO_SET_MODE:
            main, sub = int(m.param2), int(m.param3)
            if main == PX4_OFFBOARD and self.t - self.last_sp_t > OF_LOSS_S:
                self.ack(c, M.MAV_RESULT_DENIED)
                return
            self.main, self.sub = main, sub
            self.ack(c, M.MAV_RESULT_ACCEPTED)
            self.ack(c, M.MAV_RESULT_ACCEPTED)  # PX4 may answer DO_SET_MODE twice
        elif c == M.MAV_CMD_COMPONENT_ARM_DISARM and m.param1 == 1:
            if self.main == PX4_OFFBOARD and not self.armed:
                self.ack(c, M.MAV_RESULT_TEMPORARILY_REJECTED)
                self.text("Resolve system health failures first", delay=0.124)
            else:
                self.armed = True
                self.ack(c, M.MAV_RESULT_ACCEPTED)
        elif c == M.MAV_CMD_NAV_TAKEOFF:
            if not self.armed:
                self.ack(c, M.MAV_RESULT_DENIED)
                return
            self.takeoff_alt = m.param7 - HOME[2]  # AMSL
            self.main, self.sub = PX4_AUTO, PX4_TAKEOFF
            self.ack(c, M.MAV_RESULT_ACCEPTED)
        elif c == M.MAV_CMD_NAV_LAND:
            self.main, self.sub = PX4_AUTO, PX4_LAND
            self.ack(c, M.MAV_RESULT_ACCEPTED)
        else:
            super()._command(m)

    def _step(self) -> None:
        was_taking_off = self.takeoff_alt is not None
        super()._step()
        if was_taking_off and self.takeoff_alt is None:
            self.main, self.sub = PX4_AUTO, PX4_LOITER  # AUTO.TAKEOFF ends in Hold
        if self.main == PX4_OFFBOARD and self.armed and self.t - self.last_sp_t > OF_LOSS_S:
            self.main, self.sub = PX4_AUTO, PX4_LOITER  # offboard lost


@pytest.mark.timeout(240)
def test_scripted_px4_second_mission_arms_because_the_stream_stops_before_the_landing_ends():
    seen, refusals = {}, []

    def missions(v):
        yield from wait_ready(v)
        prof = v.profile
        for mission in range(2):
            yield from recipe(v, prof.takeoff_steps(10.0, v.home_amsl_m))
            seen[f"alt_{mission}"] = -v.tel.pos_ned[2]  # param 7 was read as AMSL: 594 m
            yield from recipe(v, prof.handover_steps())
            seen[f"ai_{mission}"] = v.tel.mode_name
            v.send(reposition_command(v.tel, prof, v.target_system, np.array([5.0, 0.0, -10.0])))
            yield from recipe(v, prof.land_steps() + prof.end_steps())
            seen[f"end_{mission}"] = (v.tel.armed, v.tel.mode_name)
        # the failure the issue measured, on purpose: setpoints reaching it landed and disarmed
        yield from set_mode(v, FlightMode.LAND)  # as it is when a landing has just ended
        for _ in range(3):
            v.position_target(v.tel.pos_ned)
            yield
        yield from wait_until(v, lambda: v.tel.mode_name == "OFFBOARD", 5.0, "OFFBOARD")
        try:
            yield from command(v, M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0)
        except CommandRefused as e:
            refusals.append(str(e))

    with ScriptedPx4(14610) as peer:
        v = fly("udpout:127.0.0.1:14610", Steps(), missions)
    assert v.profile.name == "PX4"
    for mission in range(2):
        assert 9.4 < seen[f"alt_{mission}"] and seen[f"ai_{mission}"] == "OFFBOARD"
        assert seen[f"end_{mission}"] == (False, "AUTO.LOITER")
    assert peer.disarmed_in_offboard == 1  # only the deliberate one, after the two missions
    assert peer.reposition_results and set(peer.reposition_results) == {M.MAV_RESULT_ACCEPTED}
    (refused,) = refusals
    assert "TEMPORARILY_REJECTED" in refused and "Resolve system health" in refused


class ScriptedArduPlane(ScriptedArduCopter):
    """A scripted ArduPlane (kinematic, not aerodynamic): mode numbers of the plane table;
    TAKEOFF (13) climbs to TKOFF_ALT once armed and circles there; NAV_TAKEOFF as COMMAND_LONG
    is refused (quadplanes only); GUIDED (15) flies to DO_REPOSITION targets (COMMAND_INT,
    global frames) and ignores SET_POSITION_TARGET_LOCAL_NED positions; LOITER (12) circles."""

    def __init__(self, port: int):
        super().__init__(port, ekf_after_s=2.0, mav_type=M.MAV_TYPE_FIXED_WING)
        self.params = {"TKOFF_ALT": 50.0}
        self.repositions: list[tuple[int, float]] = []  # (frame, peer time)
        self.local_setpoints = 0

    def _on(self, m) -> None:
        t = m.get_type()
        if t == "PARAM_SET":
            name = m.param_id if isinstance(m.param_id, str) else m.param_id.decode()
            name = name.rstrip("\x00")
            if name in self.params:
                self.params[name] = m.param_value
                self.send(M.MAVLink_param_value_message(name.encode(), m.param_value,
                                                        M.MAV_PARAM_TYPE_REAL32, len(self.params), 0))  # fmt: skip
            return
        if t == "SET_POSITION_TARGET_LOCAL_NED":
            self.local_setpoints += 1
            return  # ArduPlane: only an altitude change in LOCAL_OFFSET_NED; positions ignored
        if t == "COMMAND_INT" and m.command == M.MAV_CMD_DO_REPOSITION:
            if self.mode != 15 or m.frame not in (
                M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                M.MAV_FRAME_GLOBAL_INT,
            ):
                self.ack(m.command, M.MAV_RESULT_DENIED)
                return
            self.repositions.append((m.frame, self.t))
            north = math.radians(m.x / 1e7 - HOME[0]) * 6378137.0
            east = math.radians(m.y / 1e7 - HOME[1]) * 6378137.0 * math.cos(math.radians(HOME[0]))
            self.target = np.array([north, east, -m.z])
            self.ack(m.command, M.MAV_RESULT_ACCEPTED)
            return
        super()._on(m)

    def _command(self, m) -> None:
        c = m.command
        if c == M.MAV_CMD_NAV_TAKEOFF:
            self.ack(c, M.MAV_RESULT_UNSUPPORTED)  # not a quadplane
        elif c == M.MAV_CMD_COMPONENT_ARM_DISARM and m.param1 == 1 and self.mode == 13:
            super()._command(m)
            if self.armed:
                self.takeoff_alt = self.params["TKOFF_ALT"]
        else:
            super()._command(m)

    def _step(self) -> None:
        if self.armed and self.takeoff_alt is None and self.mode in (12, 13, 11):
            self.vel = np.zeros(3)  # circling about a point: the model holds it
            return
        mode = self.mode
        if mode == 15:
            self.mode = GUIDED  # the copter model's GUIDED flies to the target
        super()._step()
        self.mode = mode


@pytest.mark.timeout(240)
@pytest.mark.slow
def test_scripted_arduplane_takes_off_in_takeoff_mode_and_flies_reposition_targets():
    seen = {}

    def flight(v):
        yield from wait_ready(v)
        prof = v.profile
        yield from recipe(v, prof.takeoff_steps(40.0, v.home_amsl_m))
        seen["takeoff"] = (-v.tel.pos_ned[2], v.tel.mode_name, peer.arm_attempts)
        target = Setpoint(pos_ned=np.array([200.0, 0.0, -40.0]))
        yield from recipe(v, prof.handover_steps(), hold=lambda: target)
        seen["ai"] = v.tel.mode_name
        yield from wait_until(v, lambda: np.linalg.norm(v.tel.pos_ned[:2] - [200, 0]) < 5, 80.0,
                              "the target")  # fmt: skip
        yield from set_mode(v, prof.fallback_mode)
        seen["fallback"] = v.tel.mode_name
        yield from recipe(v, prof.land_steps())
        seen["end"] = (v.tel.mode_name, v.setpoint)
        yield from wait_s(v, 2.0)

    with ScriptedArduPlane(14611) as peer:
        fly("udpout:127.0.0.1:14611", Steps(), flight)
    alt, mode, attempts = seen["takeoff"]
    assert peer.params["TKOFF_ALT"] == 40.0 and attempts == 2  # retried
    assert alt >= 34.0 and mode == "TAKEOFF"
    assert M.MAV_CMD_NAV_TAKEOFF not in [cmd for _, cmd, _ in peer.commands]
    assert seen["ai"] == "GUIDED" and seen["fallback"] == "LOITER"
    frames = {f for f, _ in peer.repositions}
    assert frames == {M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT} and peer.local_setpoints == 0
    t = [t for _, t in peer.repositions]
    assert len(t) - 1 <= (t[-1] - t[0]) / 0.95  # ~1 Hz: each one is a new guided waypoint
    assert seen["end"] == ("RTL", None)
