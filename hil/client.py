"""skyherd's own MAVLink client: talks to our SITL or a real PX4 / ArduCopter / ArduPlane.

It finds the autopilot from its HEARTBEAT (hil/autopilots.py), asks for the telemetry streams
that autopilot sends, keeps the newest message of each type, speaks the command protocol with
retries and typed errors that carry the autopilot's own reasons (STATUSTEXT), executes the
profile's take-off / hand-over / landing recipes, and streams offboard setpoints paced by the
vehicle's own telemetry (one setpoint per LOCAL_POSITION_NED, requested at 20 Hz), so the
stream rate holds in simulation time at any speed-up.

Time: every limit a recipe waits under is counted on the autopilot's clock (`time_boot_ms` of
its telemetry), with a wall-clock backstop; a link silent for `silence_s` of wall time ends
any wait. A mode change the client did not request (a failsafe, a ground station, a pilot)
counts in `Telemetry.unrequested_mode_change`; from then on the client sends no setpoint and
requests no mode: the autopilot has the vehicle.

`update_telemetry(tel, msg, profile)` is the whole message → Telemetry step as a pure
function, for a single-threaded caller that has no receive thread.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode
from flight.frames import euler_to_quat
from flight.geo import GRAVITY, Home, ned_to_geodetic
from flight.mavlink.modes import Personality
from flight.mavlink.offboard import IGNORE_ACC, IGNORE_POS, IGNORE_VEL, IGNORE_YAW, IGNORE_YAW_RATE
from flight.state import VehicleState
from hil.autopilots import (
    COMPANION_COMPONENT,
    EKF_POSITION_OK,
    MSG,
    AutopilotProfile,
    Step,
    UnknownAutopilot,
    UnsupportedMode,
    detect,
    refine,
)
from hil.link import MavlinkLink

M = mavlink2
ON_GROUND, IN_AIR = M.MAV_LANDED_STATE_ON_GROUND, M.MAV_LANDED_STATE_IN_AIR
STATUSTEXT_CHUNK = 50  # characters in one STATUSTEXT; a shorter chunk ends the text
MAX_TEXTS = 200  # STATUSTEXTs kept in Telemetry (the newest)


class CommandError(Exception):
    """A command was not accepted. `result` is the MAV_RESULT (or None on timeout); `reason`
    the autopilot's own words (STATUSTEXT), if it gave any."""

    def __init__(self, command: int, result: int | None, detail: str = ""):
        name = M.enums["MAV_CMD"].get(command)
        cname = name.name if name else str(command)
        rname = "TIMEOUT" if result is None else M.enums["MAV_RESULT"][result].name
        said = f" — the autopilot says: {detail}" if detail else ""
        super().__init__(f"{cname} failed: {rname}{said}")
        self.command, self.result, self.reason = command, result, detail


class ClientTimeout(Exception):
    """The vehicle did not answer or reach a state in time."""


class Yielded(ClientTimeout):
    """The autopilot changed mode on its own (failsafe, ground station, pilot): it has the
    vehicle, and the companion must not take it back."""


@dataclass(frozen=True)
class ClientOptions:
    """Limits of the client [s of autopilot time unless said otherwise]."""

    statustext_wait_s: float = 0.3  # a refused command's reason arrives ~100 ms after its ACK
    silence_s: float = 10.0  # [s wall] no message at all for this long ends any wait
    mode_wait_s: float = 5.0  # the heartbeat shows a requested mode within this
    ground_wait_s: float = 30.0
    climb_wait_s: float = 120.0
    land_wait_s: float = 240.0
    stall_s: float = 20.0  # a position target not approached by 1 m in this long is a stall
    loiter_reach_m: float = 150.0  # a fixed-wing circling its target this close has reached it
    stall_dist_m: float = 3.0  # ... when farther than this
    version_wait_s: float = 3.0
    # Yield to the autopilot's own mode changes (the rule; default). False keeps them
    # visible (Telemetry.unrequested_mode_change, .yielded) but lets the mission go on and
    # switch back — for missions on the built-in vehicle that re-engage by design.
    yield_to_autopilot: bool = True


@dataclass
class Telemetry:
    """The client's view of the vehicle (SI, NED about home)."""

    time_boot_ms: int = 0
    armed: bool = False
    mode: FlightMode | None = None
    personality: Personality = Personality.PX4
    pos_ned: np.ndarray | None = None  # about home (LOCAL_POSITION_NED less home's x, y, z)
    vel_ned: np.ndarray | None = None
    quat: np.ndarray | None = None  # (w, x, y, z) body FRD → NED
    omega_frd: np.ndarray | None = None  # [rad/s]
    landed_state: int = 0
    home_ok: bool = False
    statustext: str = ""
    # --- added for real autopilots -----------------------------------------------------------
    profile: AutopilotProfile | None = None
    custom_mode: int | None = None
    mode_name: str = ""  # the autopilot's own name (BRAKE, AUTO.LOITER, ...)
    system_status: int = 0
    home: Home | None = None  # home position (latitude, longitude, AMSL)
    home_local: np.ndarray = field(default_factory=lambda: np.zeros(3))  # home in LOCAL_NED
    gps_fix: int | None = None
    ekf_flags: int | None = None
    prearm_ok: bool | None = None  # SYS_STATUS pre-arm bit (None: not reported)
    extended_sys_state_seen: bool = False
    quaternion_seen: bool = False
    statustexts: list[tuple[float, int, str]] = field(default_factory=list)  # (t, severity, text)
    statustext_total: int = 0  # STATUSTEXTs received in all (statustexts keeps the newest)
    modes: list[tuple[float, str, bool]] = field(default_factory=list)  # (t, name, requested)
    requested_mode: FlightMode | None = None  # the client's last request (None: no authority)
    previous_mode: FlightMode | None = None  # the mode before that request, while it is answered
    unrequested_mode_change: int = 0
    yielded: str = ""  # why the autopilot has the vehicle (empty: the client has it)
    reboots: int = 0
    _chunks: dict[int, list[str]] = field(default_factory=dict, repr=False)

    @property
    def t(self) -> float:
        """The autopilot's time [s]."""
        return self.time_boot_ms / 1000.0

    def vehicle_state(self) -> VehicleState | None:
        """The telemetry as a VehicleState (None until position and attitude arrived)."""
        if self.pos_ned is None or self.quat is None:
            return None
        return VehicleState(
            t=self.time_boot_ms / 1000.0,
            pos_ned=self.pos_ned,
            vel_ned=self.vel_ned,
            quat=self.quat,
            omega_frd=self.omega_frd if self.omega_frd is not None else np.zeros(3),
            accel_frd=np.array([0.0, 0.0, -GRAVITY]),
            on_ground=self.landed_state == ON_GROUND,
        )


def update_telemetry(tel: Telemetry, msg, profile: AutopilotProfile | None = None) -> None:
    """Apply one message from the autopilot (component 1 of the vehicle) to `tel`.

    `profile` overrides the one detected from the first HEARTBEAT (kept in `tel.profile`).
    Raises UnknownAutopilot for a HEARTBEAT of an autopilot skyherd cannot fly."""
    t = msg.get_type()
    if profile is not None:
        tel.profile = profile
    if hasattr(msg, "time_boot_ms") and t != "HEARTBEAT":
        _advance_clock(tel, int(msg.time_boot_ms))
    if t == "HEARTBEAT":
        if tel.profile is None:
            tel.profile = detect(msg.autopilot, msg.type)
        _on_heartbeat(tel, msg)
    elif t == "LOCAL_POSITION_NED":
        tel.pos_ned = np.array([msg.x, msg.y, msg.z]) - tel.home_local
        tel.vel_ned = np.array([msg.vx, msg.vy, msg.vz])
        _derive_landed(tel)
    elif t == "ATTITUDE_QUATERNION":
        tel.quaternion_seen = True
        tel.quat = np.array([msg.q1, msg.q2, msg.q3, msg.q4])
        tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
    elif t == "ATTITUDE" and not tel.quaternion_seen:
        tel.quat = euler_to_quat(msg.roll, msg.pitch, msg.yaw)
        tel.omega_frd = np.array([msg.rollspeed, msg.pitchspeed, msg.yawspeed])
    elif t == "EXTENDED_SYS_STATE":
        tel.extended_sys_state_seen = True
        tel.landed_state = msg.landed_state
    elif t == "HOME_POSITION":
        tel.home_ok = True
        tel.home = Home(msg.latitude / 1e7, msg.longitude / 1e7, msg.altitude / 1000.0)
        new = np.array([msg.x, msg.y, msg.z], dtype=float)
        if tel.pos_ned is not None:
            tel.pos_ned = tel.pos_ned + tel.home_local - new
        tel.home_local = new
    elif t == "GPS_RAW_INT":
        tel.gps_fix = msg.fix_type
    elif t == "EKF_STATUS_REPORT":
        tel.ekf_flags = msg.flags
    elif t == "SYS_STATUS":
        if msg.onboard_control_sensors_present & M.MAV_SYS_STATUS_PREARM_CHECK:
            tel.prearm_ok = bool(msg.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
    elif t == "STATUSTEXT":
        text = _join_statustext(tel, msg)
        if text is not None:
            tel.statustext = text
            tel.statustexts.append((tel.t, int(msg.severity), text))
            tel.statustext_total += 1
            if len(tel.statustexts) > 2 * MAX_TEXTS:
                del tel.statustexts[:-MAX_TEXTS]


def texts_since(tel: Telemetry, total: int) -> list[str]:
    """The STATUSTEXTs that arrived since `tel.statustext_total` was `total`."""
    k = min(tel.statustext_total - total, len(tel.statustexts))
    return [x for _, _, x in tel.statustexts[-k:]] if k > 0 else []


def _advance_clock(tel: Telemetry, ms: int) -> None:
    if ms >= tel.time_boot_ms:
        tel.time_boot_ms = ms
    elif tel.time_boot_ms - ms > 5000:  # the clock went back by more than any reordering
        tel.time_boot_ms = ms
        tel.reboots += 1


def _on_heartbeat(tel: Telemetry, msg) -> None:
    p = tel.profile
    tel.personality = p.personality
    tel.armed = bool(msg.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
    tel.system_status = msg.system_status
    if not msg.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
        return
    if tel.custom_mode != msg.custom_mode:
        mode, name = p.decode_mode(msg.custom_mode), p.mode_name(msg.custom_mode)
        requested = (
            tel.requested_mode is None
            or mode is tel.requested_mode
            or (tel.previous_mode is not None and mode is tel.previous_mode)
        )
        tel.modes.append((tel.t, name, requested))
        if tel.requested_mode is not None and mode is tel.requested_mode:
            tel.previous_mode = None
        if not requested:
            tel.unrequested_mode_change += 1
        if not requested and not tel.yielded and tel.armed:  # in flight: it has the vehicle
            tel.yielded = (
                f"the autopilot switched to {name} at t = {tel.t:.1f} s (skyherd had asked for "
                f"{tel.requested_mode.name}): its failsafe, a ground station or a pilot has the "
                "vehicle" + _recent_texts(tel)
            )
        tel.custom_mode, tel.mode, tel.mode_name = msg.custom_mode, mode, name
    _derive_landed(tel)


def _recent_texts(tel: Telemetry, within_s: float = 2.0) -> str:
    said = dict.fromkeys(x for t, _, x in tel.statustexts[-8:] if t >= tel.t - within_s)
    return f"; it says: {' / '.join(said)}" if said else ""


def _derive_landed(tel: Telemetry) -> None:
    """Landed state where the autopilot sends no EXTENDED_SYS_STATE (ArduPilot by default):
    disarmed is on the ground; armed, within 0.5 m of home's altitude and not moving is too."""
    if tel.extended_sys_state_seen:
        return
    if not tel.armed:
        tel.landed_state = ON_GROUND
        return
    if tel.pos_ned is None or tel.vel_ned is None:
        return
    low = -tel.pos_ned[2] < 0.5 and float(np.linalg.norm(tel.vel_ned)) < 0.5
    tel.landed_state = ON_GROUND if low else IN_AIR


def _join_statustext(tel: Telemetry, msg) -> str | None:
    """A whole STATUSTEXT: chunks with the same non-zero id are joined in chunk_seq order."""
    text = msg.text if isinstance(msg.text, str) else msg.text.decode("ascii", "replace")
    text = text.split("\x00", 1)[0]
    text_id = int(getattr(msg, "id", 0) or 0)
    if text_id == 0:
        return text
    parts = tel._chunks.setdefault(text_id, [])
    seq = int(getattr(msg, "chunk_seq", 0) or 0)
    while len(parts) <= seq:
        parts.append("")
    parts[seq] = text
    if len(text) < STATUSTEXT_CHUNK:
        del tel._chunks[text_id]
        return "".join(parts)
    if len(tel._chunks) > 16:  # a lost last chunk never completes: forget the oldest
        tel._chunks.pop(next(iter(tel._chunks)))
    return None


def local_setpoint(tel: Telemetry, target_system: int, pos_ned=None, vel_ned=None, yaw=None,
                   target_component: int = 1) -> mavlink2.MAVLink_message:  # fmt: skip
    """SET_POSITION_TARGET_LOCAL_NED for a position about home [m, NED] (home's x, y, z in
    the autopilot's local frame added back), velocity [m/s] and yaw [rad]; None: ignored."""
    mask = IGNORE_ACC | IGNORE_YAW_RATE
    home = tel.home_local
    p = [0.0, 0.0, 0.0] if pos_ned is None else [float(x + h) for x, h in zip(pos_ned, home)]
    v = [0.0, 0.0, 0.0] if vel_ned is None else [float(x) for x in vel_ned]
    mask |= IGNORE_POS if pos_ned is None else 0
    mask |= IGNORE_VEL if vel_ned is None else 0
    mask |= IGNORE_YAW if yaw is None else 0
    return M.MAVLink_set_position_target_local_ned_message(
        tel.time_boot_ms, target_system, target_component, M.MAV_FRAME_LOCAL_NED, mask, *p, *v,
        0.0, 0.0, 0.0, 0.0 if yaw is None else float(yaw), 0.0,
    )  # fmt: skip


def reposition_command(tel: Telemetry, profile: AutopilotProfile, target_system: int, pos_ned,
                       yaw=None, target_component: int = 1,
                       change_mode: bool = False) -> mavlink2.MAVLink_message:  # fmt: skip
    """DO_REPOSITION as COMMAND_INT to a position about home, in the global frame the profile
    names: PX4 accepts GLOBAL_INT frames only; ArduPlane's GUIDED takes its targets this way
    (GLOBAL_RELATIVE_ALT_INT). Needs `tel.home`. `change_mode`: param 2 bit 0, switch to the
    mode that flies it as well (ArduPlane: GUIDED, refused without it in TAKEOFF; PX4: Hold);
    never for a setpoint stream, which must not undo a hold the net asked for."""
    lat, lon, amsl = ned_to_geodetic(tel.home, np.asarray(pos_ned, dtype=float))
    relative = profile.reposition_frame == M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    z = amsl - tel.home.alt_m if relative else amsl
    return M.MAVLink_command_int_message(
        target_system, target_component, profile.reposition_frame, M.MAV_CMD_DO_REPOSITION, 0, 0,
        -1.0, float(M.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE if change_mode else 0),
        0.0, math.nan if yaw is None else math.degrees(yaw),
        int(round(lat * 1e7)), int(round(lon * 1e7)), float(z),
    )  # fmt: skip


SetpointFn = Callable[[Telemetry], tuple | None]


class VehicleClient:
    """A companion-side client for one vehicle (system id `target_system`), as component 191."""

    def __init__(
        self,
        link: MavlinkLink,
        target_system: int | None = None,
        target_component: int = 1,
        component_id: int = COMPANION_COMPONENT,
        options: ClientOptions = ClientOptions(),
    ):
        self.link = link
        link.codec.tx.srcComponent = component_id  # our identity on this link (191)
        self.target_system = target_system
        self.target_component = target_component
        self.options = options
        self.telemetry = Telemetry()
        self.error: str = ""  # why the receive thread could not read the vehicle
        self._latest: dict[str, mavlink2.MAVLink_message] = {}
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._setpoint_fn: SetpointFn | None = None
        self._streaming = False
        self._hold: np.ndarray | None = None  # the client's own hold target while streaming
        self._last_sp_t = -math.inf
        self._stall: tuple[np.ndarray, float, float] | None = None  # (target, best d, since)
        self.interrupt = ""  # a reason to end the current wait (stall)
        self._acks: dict[int, int] = {}
        self._last_rx = time.monotonic()
        self._rx = threading.Thread(target=self._rx_loop, name="mav-rx", daemon=True)
        self._hb = threading.Thread(target=self._hb_loop, name="mav-hb", daemon=True)
        self.setpoints_sent = 0

    # ---- lifecycle -------------------------------------------------------------------
    def start(self) -> VehicleClient:
        self._rx.start()
        self._hb.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._rx.join(timeout=1.0)
        self._hb.join(timeout=1.0)
        self.link.close()

    def __enter__(self) -> VehicleClient:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.close()

    @property
    def profile(self) -> AutopilotProfile | None:
        return self.telemetry.profile

    # ---- receive ---------------------------------------------------------------------
    def _rx_loop(self) -> None:
        while not self._stop.is_set():
            for msg in self.link.recv(0.05):
                self._last_rx = time.monotonic()
                self._handle(msg)

    def _hb_loop(self) -> None:
        while not self._stop.wait(1.0):
            self.link.send(
                M.MAVLink_heartbeat_message(
                    M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE, 3
                )
            )

    def _handle(self, msg: mavlink2.MAVLink_message) -> None:
        src, comp = msg.get_srcSystem(), msg.get_srcComponent()
        t = msg.get_type()
        if self.target_system is None and t == "HEARTBEAT" and comp == self.target_component:
            if msg.type in (M.MAV_TYPE_GCS, M.MAV_TYPE_ONBOARD_CONTROLLER):
                return  # another ground station or companion on the same link
            self.target_system = src
        if src != self.target_system or (t == "HEARTBEAT" and comp != self.target_component):
            return
        tel = self.telemetry
        try:
            update_telemetry(tel, msg)
        except UnknownAutopilot as e:
            self.error = str(e)
        if t == "COMMAND_ACK":
            self._acks[msg.command] = msg.result
        elif t == "LOCAL_POSITION_NED":
            self._on_position(tel)
        with self._cond:
            self._latest[t] = msg
            self._cond.notify_all()

    def _on_position(self, tel: Telemetry) -> None:
        """One telemetry sample: ask the mission for its setpoint and send it while streaming.
        A mission function that fails is reported in `error` and the client holds position
        (the receive thread must live on)."""
        try:
            sp = self._setpoint_fn(tel) if self._setpoint_fn is not None else None
        except Exception as e:  # noqa: BLE001 - never let the receive thread die
            self.error = f"setpoint function failed at t={tel.t:.1f} s: {type(e).__name__}: {e}"
            self._setpoint_fn, sp = None, None
            if self._hold is None and tel.pos_ned is not None:
                self._hold = tel.pos_ned.copy()
        if not self._streaming or self.yielded:
            return
        if sp is None and self._hold is not None:
            sp = (self._hold, None, None)
        if sp is None:
            return
        self._watch_progress(tel, sp[0])
        msg = self.setpoint_message(*sp)
        if msg is not None:
            self.link.send(msg)
            self.setpoints_sent += 1

    def _watch_progress(self, tel: Telemetry, target) -> None:
        """A position target the vehicle does not approach (ArduPilot's fence avoidance or a
        refused target) becomes `interrupt` instead of a silent wait until the timeout."""
        if target is None or tel.pos_ned is None or tel.mode is not self._ai_mode():
            self._stall = None
            return
        target = np.asarray(target, dtype=float)
        d = float(np.linalg.norm(tel.pos_ned - target))
        if self.profile is not None and self.profile.vehicle == "fixedwing":  # it circles it
            d = max(
                0.0, float(np.linalg.norm((tel.pos_ned - target)[:2])) - self.options.loiter_reach_m
            )
        now = tel.t
        st = self._stall
        if st is None or np.linalg.norm(st[0] - target) > 5.0 or d < st[1] - 1.0:
            self._stall = (target, d, now)
            return
        if d > self.options.stall_dist_m and now - st[2] > self.options.stall_s:
            said = [x for _, _, x in tel.statustexts[-8:] if "ence" in x or "void" in x]
            said = list(dict.fromkeys(said or [x for _, _, x in tel.statustexts[-2:]]))
            self.interrupt = (
                f"position target {d:.0f} m away not approached for {now - st[2]:.0f} s "
                f"({self.profile.name if self.profile else 'autopilot'} in {tel.mode_name})"
                + (f"; the autopilot says: {' / '.join(said)}" if said else "")
            )

    def _ai_mode(self) -> FlightMode:
        return self.profile.ai_mode if self.profile else FlightMode.OFFBOARD

    @property
    def yielded(self) -> str:
        """Why the autopilot has the vehicle, when the client yields to it (else empty)."""
        return self.telemetry.yielded if self.options.yield_to_autopilot else ""

    @property
    def statustexts(self) -> list[str]:
        """The autopilot's STATUSTEXTs (the newest MAX_TEXTS), whole (chunks joined)."""
        return [x for _, _, x in self.telemetry.statustexts]

    def latest(self, msg_type: str) -> mavlink2.MAVLink_message | None:
        return self._latest.get(msg_type)

    # ---- waiting ---------------------------------------------------------------------
    def wait_until(
        self,
        predicate: Callable[[], bool],
        timeout: float,
        what: str,
        vehicle_s: float | None = None,
        interruptible: bool = True,
    ) -> None:
        """Wait until `predicate()` holds: at most `timeout` [s wall] and, if given,
        `vehicle_s` [s of the autopilot's clock]. Raises ClientTimeout naming `what`, and
        Yielded / ClientTimeout at once when the autopilot took over or the vehicle stalled
        (`interruptible`), or when the link has been silent for `options.silence_s`."""
        deadline = time.monotonic() + timeout
        tel = self.telemetry
        t0 = tel.t if tel.time_boot_ms else None  # the autopilot's clock starts at its first stamp
        with self._cond:
            while not predicate():
                if interruptible and self.yielded:
                    raise Yielded(self.yielded)
                if interruptible and self.interrupt:
                    raise ClientTimeout(f"{self.interrupt} (while waiting for {what})")
                now = time.monotonic()
                if now >= deadline:
                    raise ClientTimeout(f"timed out after {timeout:.0f} s waiting for {what}")
                if t0 is None and tel.time_boot_ms:
                    t0 = tel.t
                if vehicle_s is not None and t0 is not None and tel.t - t0 > vehicle_s:
                    raise ClientTimeout(
                        f"timed out after {vehicle_s:.0f} s of autopilot time waiting for {what}"
                        + self._said()
                    )
                if now - self._last_rx > self.options.silence_s:
                    raise ClientTimeout(
                        f"no message from the vehicle for {self.options.silence_s:.0f} s while "
                        f"waiting for {what}: is it running and the link address right?"
                    )
                self._cond.wait(min(deadline - now, 0.1))

    def _said(self) -> str:
        last = self.telemetry.statustexts[-2:]
        return ("; the autopilot last said: " + " / ".join(x for _, _, x in last)) if last else ""

    def wait_message(self, msg_type: str, timeout: float = 5.0) -> mavlink2.MAVLink_message:
        before = self._latest.get(msg_type)
        self.wait_until(lambda: self._latest.get(msg_type) not in (None, before), timeout, msg_type)
        return self._latest[msg_type]

    def wait_vehicle_s(self, seconds: float, timeout: float = 60.0) -> None:
        """Let `seconds` of the autopilot's time pass."""
        t0 = self.telemetry.t
        self.wait_until(lambda: self.telemetry.t - t0 >= seconds, timeout,
                        f"{seconds:.1f} s of autopilot time", interruptible=False)  # fmt: skip

    def wait_connected(self, timeout: float = 10.0) -> None:
        self.wait_until(
            lambda: self.error or (self.target_system is not None and self.profile is not None),
            timeout,
            "a vehicle heartbeat",
        )
        if self.error:
            raise ClientTimeout(self.error)

    def wait_ready(self, timeout: float = 300.0) -> None:
        """Heartbeat, the streams this autopilot needs, then a position it navigates by and
        home — waited for by condition, up to the profile's `ready_timeout_s` of autopilot
        time (ArduCopter's EKF takes ~40 s after boot to use GPS); `timeout` is the wall cap."""
        t_wall = time.monotonic()
        self.wait_connected(min(timeout, 30.0))
        self._identify()
        self.request_streams()
        tel, p = self.telemetry, self.profile
        asked = {"t": -math.inf}

        def ready() -> bool:
            if tel.t - asked["t"] >= 2.0:
                asked["t"] = tel.t
                self.send_command_long(M.MAV_CMD_REQUEST_MESSAGE, MSG["HOME_POSITION"])
            return not self._not_ready()

        left = max(1.0, timeout - (time.monotonic() - t_wall))
        try:
            self.wait_until(ready, left, "readiness", vehicle_s=p.ready_timeout_s)
        except ClientTimeout as e:
            raise ClientTimeout(f"{e}; still missing: {', '.join(self._not_ready())}") from None

    def _not_ready(self) -> list[str]:
        tel, out = self.telemetry, []
        if tel.pos_ned is None:
            out.append("local position (LOCAL_POSITION_NED)")
        if tel.quat is None:
            out.append("attitude")
        if not tel.home_ok:
            out.append("home (HOME_POSITION)")
        if tel.gps_fix is not None and tel.gps_fix < M.GPS_FIX_TYPE_3D_FIX:
            out.append(f"a 3D GPS fix (fix type {tel.gps_fix})")
        if tel.ekf_flags is not None and tel.ekf_flags & EKF_POSITION_OK != EKF_POSITION_OK:
            out.append(f"an EKF position (EKF_STATUS_REPORT flags 0x{tel.ekf_flags:x})")
        if tel.prearm_ok is False and not tel.armed:
            out.append("pre-arm checks passing (SYS_STATUS)")
        return out

    def _identify(self) -> None:
        """AUTOPILOT_VERSION refines the profile: its version, and whether this is skyherd's
        built-in vehicle (whose ArduCopter personality hovers in LOITER too)."""
        before = self.latest("AUTOPILOT_VERSION")
        self.send_command_long(M.MAV_CMD_REQUEST_MESSAGE, MSG["AUTOPILOT_VERSION"])
        try:
            self.wait_until(lambda: self.latest("AUTOPILOT_VERSION") not in (None, before),
                            self.options.version_wait_s * 4, "AUTOPILOT_VERSION",
                            vehicle_s=self.options.version_wait_s)  # fmt: skip
        except ClientTimeout:
            return  # old firmware: the heartbeat's profile stands
        self.telemetry.profile = refine(self.profile, self.latest("AUTOPILOT_VERSION"))

    def request_streams(self) -> None:
        """SET_MESSAGE_INTERVAL for each message the profile reads; REQUEST_DATA_STREAM when
        the autopilot answers none of them (older firmware)."""
        answered = 0
        for msg_id, hz in self.profile.stream_requests():
            try:
                self.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, msg_id, 1e6 / hz,
                                  retries=2, timeout=0.5, reason_wait=False)  # fmt: skip
                answered += 1
            except CommandError as e:
                answered += e.result not in (None, M.MAV_RESULT_UNSUPPORTED)
        if answered == 0:
            for stream_id, hz in self.profile.data_stream_requests():
                self.link.send(M.MAVLink_request_data_stream_message(
                    self.target_system, self.target_component, stream_id, int(round(hz)), 1))  # fmt: skip

    # ---- commands --------------------------------------------------------------------
    def send_command_long(self, command: int, *params: float, confirmation: int = 0) -> None:
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.link.send(M.MAVLink_command_long_message(
            self.target_system or 1, self.target_component, command, confirmation, *p))  # fmt: skip

    def command_long(
        self, command: int, *params: float, timeout: float = 1.5, retries: int = 3,
        reason_wait: bool = True,
    ) -> int:  # fmt: skip
        """COMMAND_LONG until acknowledged (confirmation counts up on each re-send); return
        MAV_RESULT_ACCEPTED, or raise CommandError with the autopilot's STATUSTEXT reasons
        (which arrive up to ~100 ms after the ACK: waited for `statustext_wait_s`)."""
        tel = self.telemetry
        n_text = tel.statustext_total
        for confirmation in range(retries):
            self._acks.pop(command, None)
            self.send_command_long(command, *params, confirmation=confirmation)
            try:
                self.wait_until(lambda: command in self._acks, timeout, "COMMAND_ACK",
                                interruptible=False)  # fmt: skip
            except ClientTimeout:
                continue
            result = self._acks[command]
            if result in (M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_IN_PROGRESS):
                return result  # IN_PROGRESS: running (a landing); the recipe waits for its end
            if reason_wait:
                self._wait_reason(n_text)
            reason = "; ".join(texts_since(tel, n_text))
            raise CommandError(command, result, reason)
        raise CommandError(command, None, "; ".join(texts_since(tel, n_text)))

    def _wait_reason(self, n_text: int) -> None:
        """Let `statustext_wait_s` of autopilot time pass (wall backstop 1 s + that)."""
        tel, wait = self.telemetry, self.options.statustext_wait_s
        t0 = tel.t
        try:
            self.wait_until(lambda: tel.t - t0 >= wait, 1.0 + wait, "a STATUSTEXT",
                            interruptible=False)  # fmt: skip
        except ClientTimeout:
            pass

    def request_message(self, msg_id: int) -> None:
        try:
            self.command_long(M.MAV_CMD_REQUEST_MESSAGE, msg_id, retries=1, timeout=0.5)
        except CommandError:
            pass  # older autopilots: the stream will bring it anyway

    def arm(self, force: bool = False) -> None:
        self.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196 if force else 0)

    def disarm(self, force: bool = False) -> None:
        self.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196 if force else 0)

    def set_mode(self, mode: FlightMode, authority: bool = True) -> None:
        """DO_SET_MODE for `mode` as this autopilot numbers it (UnsupportedMode if it has none);
        refused once the autopilot took over (Yielded). With `authority` the client holds
        the vehicle from now on: any mode it did not request then counts as the autopilot's."""
        tel = self.telemetry
        if self.yielded:
            raise Yielded(self.yielded)
        params = self.profile.set_mode_params(mode)
        if not authority:  # a take-off: the autopilot's own mode changes are expected
            tel.previous_mode = tel.requested_mode = None
        elif tel.requested_mode is not mode:
            tel.previous_mode, tel.requested_mode = tel.mode, mode
        self.command_long(M.MAV_CMD_DO_SET_MODE, *params)

    def takeoff(self, altitude: float) -> None:
        """NAV_TAKEOFF the way this autopilot reads param 7 (PX4 AMSL, ArduCopter above home)."""
        steps = self.profile.takeoff_steps(altitude, self.home_amsl())
        (step,) = [s for s in steps if s.command == M.MAV_CMD_NAV_TAKEOFF]
        self.command_long(step.command, *step.params)

    def land(self) -> None:
        """The profile's landing up to (not including) the wait for the disarm: the setpoint
        stream stops once the landing is under way."""
        steps = [s for s in self.profile.land_steps() if s.kind != "wait_disarmed"]
        self.run_steps(tuple(steps), budget_s=60.0)

    def home_amsl(self) -> float:
        home = self.telemetry.home
        return home.alt_m if home is not None else 0.0

    # ---- parameters ------------------------------------------------------------------
    def read_param(self, name: str, timeout: float = 3.0) -> float:
        """PARAM_REQUEST_READ until PARAM_VALUE answers `name`."""
        return self._param(name, None, timeout)

    def set_param(self, name: str, value: float, timeout: float = 3.0) -> float:
        """PARAM_SET until PARAM_VALUE echoes `value` (ArduPilot and PX4 both echo)."""
        return self._param(name, float(value), timeout)

    def param_si(self, key: str, timeout: float = 3.0) -> float:
        """A setting by its ParamNames key (`airspeed_trim`, `loiter_radius`, ...), read under
        this autopilot's own name and converted to SI (ValueError: it has no such parameter)."""
        p = self.profile
        return p.param_to_si(key, self.read_param(p.param_name(key), timeout))

    def _param(self, name: str, value: float | None, timeout: float) -> float:
        got: dict[str, float] = {}
        before = self.latest("PARAM_VALUE")

        def answered() -> bool:
            m = self.latest("PARAM_VALUE")
            if m is None or m is before or m.param_id.rstrip("\x00") != name:
                return False
            got["v"] = float(m.param_value)
            return value is None or abs(got["v"] - value) <= 1e-3 * max(1.0, abs(value))

        for _ in range(3):
            if value is None:
                self.link.send(M.MAVLink_param_request_read_message(
                    self.target_system, self.target_component, name.encode(), -1))  # fmt: skip
            else:
                self.link.send(M.MAVLink_param_set_message(
                    self.target_system, self.target_component, name.encode(), value,
                    M.MAV_PARAM_TYPE_REAL32))  # fmt: skip
            try:
                self.wait_until(answered, timeout / 3, f"parameter {name}", interruptible=False)
                return got["v"]
            except ClientTimeout:
                continue
        raise ClientTimeout(f"parameter {name} not answered" + self._said())

    # ---- offboard --------------------------------------------------------------------
    def stream_offboard(self, setpoint: SetpointFn | None) -> None:
        """Call `setpoint(tel)` on every LOCAL_POSITION_NED; it returns (pos_ned or None,
        vel_ned or None, yaw or None) or None, sent while streaming is on (from now on, until
        `stop_setpoints`; a recipe turns it off and on). None removes `setpoint` and stops."""
        self._setpoint_fn = setpoint
        if setpoint is None:
            self.stop_setpoints()
        else:
            self._streaming = True

    def start_setpoints(self, hold_ned: np.ndarray | None = None) -> None:
        """Send setpoints from now on; when the mission gives none, hold `hold_ned`
        (default: where the vehicle is)."""
        tel = self.telemetry
        if hold_ned is None and tel.pos_ned is not None:
            hold_ned = tel.pos_ned.copy()
        self._hold = None if hold_ned is None else np.asarray(hold_ned, dtype=float)
        self._last_sp_t = -math.inf
        self._streaming = True

    def stop_setpoints(self) -> None:
        self._streaming = False
        self._hold = None
        self._stall = None

    @property
    def streaming(self) -> bool:
        return self._streaming

    def setpoint_message(self, pos_ned=None, vel_ned=None, yaw=None):
        """The setpoint in the frame this autopilot accepts (None: not sent this sample)."""
        p = self.profile
        if p is not None and p.setpoint_frame == "reposition":
            tel = self.telemetry
            if pos_ned is None and vel_ned is not None and tel.pos_ned is not None:
                pos_ned = tel.pos_ned + p.reposition_lead_s * np.asarray(vel_ned, float)
            if pos_ned is None or tel.home is None:
                return None  # ArduPlane's GUIDED takes positions only: a velocity → a point ahead
            if tel.t - self._last_sp_t < p.setpoint_min_interval_s:
                return None
            self._last_sp_t = tel.t
            return self.reposition_message(pos_ned, yaw)
        return self.position_target(pos_ned, vel_ned, yaw)

    def position_target(self, pos_ned=None, vel_ned=None, yaw=None) -> mavlink2.MAVLink_message:
        """SET_POSITION_TARGET_LOCAL_NED (position about home → the autopilot's local frame)."""
        return local_setpoint(self.telemetry, self.target_system or 1, pos_ned, vel_ned, yaw,
                              self.target_component)  # fmt: skip

    def reposition_message(self, pos_ned, yaw=None) -> mavlink2.MAVLink_message:
        """DO_REPOSITION as COMMAND_INT in the global frame the profile names."""
        return reposition_command(self.telemetry, self.profile, self.target_system or 1, pos_ned,
                                  yaw, self.target_component)  # fmt: skip

    # ---- recipes ---------------------------------------------------------------------
    def run_steps(
        self, steps: tuple[Step, ...], budget_s: float, hold_ned=None, authority: bool = True
    ) -> None:
        """Execute a profile's recipe; `budget_s` [s wall] caps each wait; `hold_ned` is
        the hold target of a "stream_setpoints" step (default: where the vehicle is). The
        take-off runs without `authority`: the autopilot's own mode changes are expected."""
        if not authority:
            self.telemetry.requested_mode = self.telemetry.previous_mode = None
        for step in steps:
            self._run_step(step, budget_s, hold_ned, authority)

    def _run_step(self, s: Step, budget: float, hold_ned, authority: bool) -> None:
        tel, o = self.telemetry, self.options
        if s.kind == "wait_on_ground":
            self.wait_until(lambda: tel.landed_state == ON_GROUND, budget, s.what,
                            vehicle_s=o.ground_wait_s)  # fmt: skip
        elif s.kind == "set_param":
            self.set_param(s.what, s.params[0])
        elif s.kind == "stream_setpoints":
            self.start_setpoints(hold_ned)
            if s.params and s.params[0] > 0:
                self.wait_vehicle_s(s.params[0], timeout=budget)
        elif s.kind == "stop_setpoints":
            self.stop_setpoints()
        elif s.kind == "set_mode":
            self._attempts(s, lambda: self.set_mode(s.mode, authority), budget)
            self.wait_until(lambda: tel.mode is s.mode, budget, f"mode {s.what or s.mode.name}",
                            vehicle_s=o.mode_wait_s)  # fmt: skip
        elif s.kind == "arm":
            self._attempts(s, self.arm, budget)
            self.wait_until(lambda: tel.armed, budget, "armed", vehicle_s=o.mode_wait_s)
        elif s.kind == "command":
            if s.mode is not None and authority and not self.yielded:
                tel.previous_mode, tel.requested_mode = tel.mode, s.mode  # e.g. NAV_LAND
            self._attempts(s, lambda: self.command_long(s.command, *s.params), budget)
        elif s.kind == "wait_altitude":

            def climbed() -> bool:
                if not tel.armed:
                    raise ClientTimeout(f"disarmed while waiting for {s.what}" + self._said())
                return tel.pos_ned is not None and -tel.pos_ned[2] >= s.altitude_m

            self.wait_until(climbed, budget, s.what, vehicle_s=o.climb_wait_s)
        elif s.kind == "wait_disarmed":
            self.wait_until(lambda: not tel.armed, budget, s.what, vehicle_s=o.land_wait_s,
                            interruptible=False)  # fmt: skip
        else:
            raise ValueError(f"unknown recipe step {s.kind!r}")

    def _attempts(self, s: Step, action: Callable[[], None], budget: float) -> None:
        """Up to `s.retries` attempts, `s.retry_s` of autopilot time apart when refused."""
        for attempt in range(max(1, s.retries)):
            try:
                action()
                return
            except CommandError as e:
                if attempt + 1 >= max(1, s.retries) or e.result is None:
                    raise
                self.wait_vehicle_s(s.retry_s, timeout=budget)


__all__ = ["ClientOptions", "ClientTimeout", "CommandError", "Telemetry", "UnsupportedMode",
           "VehicleClient", "Yielded", "local_setpoint", "reposition_command", "texts_since",
           "update_telemetry"]  # fmt: skip
