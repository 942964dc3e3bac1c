"""Command protocol: COMMAND_LONG / COMMAND_INT → autopilot calls → COMMAND_ACK.

Every parameter is checked before anything changes: an infinite parameter, a latitude,
longitude, altitude or yaw out of range, or NaN where the spec gives NaN no meaning is refused
with MAV_RESULT_DENIED and a STATUSTEXT saying why (NaN means "keep the current value" where
the spec says so). An autopilot refusal is DENIED with its reason, or TEMPORARILY_REJECTED when
it refuses for now (a companion's mode change while the autopilot's own failsafe is in force:
`ModeSource`, by the sender's component id). Unknown commands are
UNSUPPORTED. A retry (COMMAND_LONG with confirmation > 0 and the same parameters) is answered
with the first answer and not executed twice. A command the autopilot reports as still running
is acknowledged IN_PROGRESS, then finally ACCEPTED or FAILED when it completes (or after a
timeout in simulation time). The retry table and the running commands are bounded
(MAX_RETRY_ENTRIES, MAX_PENDING; the oldest goes first), so a flood of distinct senders costs
O(1) per packet and no memory growth.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Autopilot, FlightMode, LandedState, ModeSource, Result
from skyherd.flight.geo import geodetic_to_ned
from skyherd.flight.mavlink.modes import COPTER, Personality, mode_of_custom

M = mavlink
FORCE_MAGIC = 21196.0  # param2 of COMPONENT_ARM_DISARM that forces arming / disarming
RETRY_WINDOW_S = 5.0  # [s sim] a confirmation > 0 repeat inside this window is not re-executed
IN_PROGRESS_TIMEOUT_S = 120.0  # [s sim]
MAX_ALTITUDE_M = 10_000.0  # [m above home] larger takeoff / reposition altitudes are refused
MAX_RANGE_M = 100_000.0  # [m] reposition targets farther than this from home are refused
INT32_MAX = 2**31 - 1
MAX_RETRY_ENTRIES = 256  # (sender, command) answers remembered for retries; oldest dropped
MAX_PENDING = 16  # IN_PROGRESS commands tracked at once; the oldest is answered FAILED
MAX_ABS_ALT_M = 100_000.0  # [m] |altitude| of any frame beyond this is refused
MAX_ABS_YAW = 360.0  # [deg or rad as the command gives it] |yaw| beyond this is refused
MIN_HEARTBEAT_HZ = 1.0  # HEARTBEAT cannot be stopped or slowed below this (all clients need it)
ONBOARD_COMPONENTS = frozenset(  # senders whose mode changes are a companion's (ModeSource)
    (M.MAV_COMP_ID_ONBOARD_COMPUTER, M.MAV_COMP_ID_ONBOARD_COMPUTER2,
     M.MAV_COMP_ID_ONBOARD_COMPUTER3, M.MAV_COMP_ID_ONBOARD_COMPUTER4)
)  # fmt: skip

# Commands whose param5..7 are latitude [deg], longitude [deg], altitude [m] and param4 a yaw.
_POSITIONAL = {M.MAV_CMD_NAV_TAKEOFF, M.MAV_CMD_NAV_LAND, M.MAV_CMD_DO_REPOSITION}

# Messages a ground station may ask for that this vehicle does not produce: answered
# UNSUPPORTED so that QGroundControl's connection sequence moves on.
UNSUPPORTED_MESSAGES = {
    395,  # COMPONENT_INFORMATION
    397,  # COMPONENT_METADATA
    435,  # AVAILABLE_MODES
    436,  # CURRENT_MODE
    300,  # PROTOCOL_VERSION
}


@dataclass(frozen=True)
class Cmd:
    """A command as both COMMAND_LONG and COMMAND_INT deliver it (x, y in degrees)."""

    command: int
    p: tuple[float, float, float, float, float, float, float]  # param1..7 (5, 6 as degrees)
    frame: int | None  # COMMAND_INT frame, None for COMMAND_LONG
    confirmation: int
    sender: tuple[int, int]

    @staticmethod
    def from_long(msg) -> Cmd:
        p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6, msg.param7)
        return Cmd(msg.command, tuple(float(v) for v in p), None, msg.confirmation,
                   (msg.get_srcSystem(), msg.get_srcComponent()))  # fmt: skip

    @staticmethod
    def from_int(msg) -> Cmd:
        x = float("nan") if msg.x == INT32_MAX else msg.x / 1e7
        y = float("nan") if msg.y == INT32_MAX else msg.y / 1e7
        p = (msg.param1, msg.param2, msg.param3, msg.param4, x, y, msg.z)
        return Cmd(msg.command, tuple(float(v) for v in p), msg.frame, 0,
                   (msg.get_srcSystem(), msg.get_srcComponent()))  # fmt: skip


@dataclass
class _Pending:
    command: int
    reply: Callable
    sender: tuple[int, int]
    done: Callable[[], bool | None]  # True done, False failed, None still running
    t0: float


class Denied(Exception):
    """A command refused before reaching the autopilot (bad parameter)."""


class CommandService:
    """Runs commands against the autopilot and answers them."""

    def __init__(
        self,
        ap: Autopilot,
        mav: mavlink.MAVLink,
        personality: Personality,
        statustext: Callable[[int, str], None],
        request_message: Callable[[int, Callable], int],
        set_interval: Callable[[object, int, float], bool],
        get_interval: Callable[[object, int], int],
        mission_count: Callable[[], int],
    ):
        self.ap = ap
        self.mav = mav
        self.personality = personality
        self.mode_number: int | None = None  # ArduPilot: the mode number last set (DO_SET_MODE)
        self.guided_hover = False  # ArduPilot: took off in GUIDED, no mode change since
        self.statustext = statustext
        self.request_message = request_message
        self.set_interval = set_interval
        self.get_interval = get_interval
        self.mission_count = mission_count
        # (sender, command) → (params, result, t); oldest first (t is non-decreasing).
        self._last: OrderedDict[tuple, tuple[tuple, int, float]] = OrderedDict()
        self.pending: list[_Pending] = []
        self._handlers: dict[int, Callable] = {
            M.MAV_CMD_COMPONENT_ARM_DISARM: self._arm_disarm,
            M.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            M.MAV_CMD_NAV_LAND: self._land,
            M.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._rtl,
            M.MAV_CMD_DO_SET_MODE: self._set_mode,
            M.MAV_CMD_DO_REPOSITION: self._reposition,
            M.MAV_CMD_MISSION_START: self._mission_start,
            M.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
        }
        # Every MAV_CMD answered other than UNSUPPORTED.
        self.handled = frozenset(self._handlers) | _SERVICE_COMMANDS

    # --- entry -----------------------------------------------------------------------------
    def handle(self, cmd: Cmd, reply: Callable, link: object) -> None:
        key = (cmd.sender, cmd.command)
        last = self._last.get(key)
        t = self.ap.clock.t
        if (
            cmd.confirmation > 0
            and last is not None
            and _same(last[0], cmd.p)
            and t - last[2] < RETRY_WINDOW_S
        ):
            reply(self._ack(cmd, last[1]))  # a retry of a command already executed
            return
        result = self._execute(cmd, reply, link)
        if result is not None:
            self._remember(key, cmd.p, result)
            reply(self._ack(cmd, result))

    def _remember(self, key: tuple, p: tuple, result: int) -> None:
        """Keep an answer for retries: expired entries and the oldest beyond the cap go first
        (amortised O(1): the table is ordered by time)."""
        t = self.ap.clock.t
        table = self._last
        table[key] = (p, result, t)
        table.move_to_end(key)
        while table:
            first = next(iter(table.values()))
            if len(table) <= MAX_RETRY_ENTRIES and t - first[2] < RETRY_WINDOW_S:
                break
            table.popitem(last=False)

    def service(self) -> None:
        """Finish IN_PROGRESS commands that completed, failed or timed out."""
        still = []
        for pnd in self.pending:
            state = pnd.done()
            if state is None and self.ap.clock.t - pnd.t0 > IN_PROGRESS_TIMEOUT_S:
                state = False
            if state is None:
                still.append(pnd)
                continue
            result = M.MAV_RESULT_ACCEPTED if state else M.MAV_RESULT_FAILED
            pnd.reply(
                self.mav.command_ack_encode(
                    pnd.command, result, 100 if state else 0, 0, *pnd.sender
                )
            )
        self.pending = still

    def _execute(self, cmd: Cmd, reply: Callable, link: object) -> int | None:
        c = cmd.command
        try:
            if c not in self.handled:
                return M.MAV_RESULT_UNSUPPORTED
            _check_params(cmd)
            if c == M.MAV_CMD_SET_MESSAGE_INTERVAL:
                msg_id = _int_param(cmd.p[0], 0, 2**24, "message id")
                _check_heartbeat_interval(msg_id, cmd.p[1])
                ok = self.set_interval(link, msg_id, cmd.p[1])
                if not ok:
                    raise Denied(f"cannot stream message {msg_id} at that interval")
                return M.MAV_RESULT_ACCEPTED
            if c == M.MAV_CMD_GET_MESSAGE_INTERVAL:  # MESSAGE_INTERVAL holds a uint16 id
                msg_id = _int_param(cmd.p[0], 0, 2**16 - 1, "message id")
                reply(self._ack(cmd, M.MAV_RESULT_ACCEPTED))
                reply(self.mav.message_interval_encode(msg_id, self.get_interval(link, msg_id)))
                self._remember((cmd.sender, c), cmd.p, M.MAV_RESULT_ACCEPTED)
                return None
            if c in (M.MAV_CMD_REQUEST_MESSAGE, M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES):
                msg_id = (
                    M.MAVLINK_MSG_ID_AUTOPILOT_VERSION
                    if c == M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
                    else _int_param(cmd.p[0], 0, 2**24, "message id")
                )
                if msg_id in UNSUPPORTED_MESSAGES:
                    return M.MAV_RESULT_UNSUPPORTED
                # The ACK goes first, then the message (MAVLink command protocol).
                return self.request_message(msg_id, reply, lambda r: reply(self._ack(cmd, r)))
            handler = self._handlers.get(c)
            if handler is None:
                return M.MAV_RESULT_UNSUPPORTED
            res, done = handler(cmd)
        except Denied as e:
            self.statustext(M.MAV_SEVERITY_WARNING, f"cmd {c}: {e}")
            return M.MAV_RESULT_DENIED
        if not res.ok:
            self.statustext(M.MAV_SEVERITY_WARNING, res.reason or f"command {c} denied")
            return refusal_result(res)
        if res.in_progress and done is not None:
            reply(self._ack(cmd, M.MAV_RESULT_IN_PROGRESS))
            self._track(_Pending(c, reply, cmd.sender, done, self.ap.clock.t))
            self._remember((cmd.sender, c), cmd.p, M.MAV_RESULT_IN_PROGRESS)
            return None
        return M.MAV_RESULT_ACCEPTED

    def _track(self, pnd: _Pending) -> None:
        """Follow an IN_PROGRESS command: a repeat from the same sender replaces the older
        one; beyond MAX_PENDING the oldest is answered FAILED and dropped."""
        self.pending = [
            q for q in self.pending if (q.sender, q.command) != (pnd.sender, pnd.command)
        ]
        if len(self.pending) >= MAX_PENDING:
            old = self.pending.pop(0)
            old.reply(
                self.mav.command_ack_encode(old.command, M.MAV_RESULT_FAILED, 0, 0, *old.sender)
            )
        self.pending.append(pnd)

    # --- handlers: (Result, completion predicate for IN_PROGRESS or None) -------------------
    def _arm_disarm(self, cmd: Cmd):
        p1, p2 = cmd.p[0], cmd.p[1]
        if p1 not in (0.0, 1.0):
            raise Denied("param1 must be 1 (arm) or 0 (disarm)")
        if not (math.isnan(p2) or p2 in (0.0, FORCE_MAGIC)):
            raise Denied("param2 must be 0 or 21196 (force)")
        force = p2 == FORCE_MAGIC
        if p1 == 1.0:
            return self.ap.arm(force=force), None
        return self.ap.disarm(force=force), None

    def _takeoff(self, cmd: Cmd):
        z = cmd.p[6]
        alt = None
        if not math.isnan(z):
            if math.isinf(z):
                raise Denied("altitude not finite")
            # PX4 gives AMSL; ArduCopter an altitude above home.
            alt = z - self.ap.home.alt_m if self.personality is Personality.PX4 else z
            if cmd.frame in (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT):
                alt = z
            if not 0.0 < alt <= MAX_ALTITUDE_M:
                raise Denied(f"takeoff altitude {alt:.1f} m above home out of range")
        res = self.ap.takeoff(alt)
        if res.ok and self.personality is Personality.ARDUPILOT:  # ArduCopter stays in GUIDED
            self.guided_hover = self.mode_number in (None, COPTER["GUIDED"])
        return res, self._takeoff_done

    def _takeoff_done(self) -> bool | None:
        if not self.ap.armed:
            return False
        if self.ap.landed_state == LandedState.IN_AIR and self.ap.mode != FlightMode.TAKEOFF:
            return True
        return None

    def _land(self, cmd: Cmd):
        self.guided_hover = False
        return self.ap.land(), self._on_ground

    def _rtl(self, cmd: Cmd):
        self.guided_hover = False
        return self.ap.return_to_launch(), self._on_ground

    def _on_ground(self) -> bool | None:
        return True if self.ap.landed_state == LandedState.ON_GROUND else None

    def _set_mode(self, cmd: Cmd):
        base, main, sub = cmd.p[0], cmd.p[1], cmd.p[2]
        if not (math.isfinite(base) and int(base) & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED):
            raise Denied("only custom modes can be set (base_mode bit 1)")
        mode = mode_of_custom(
            self.personality, main, 0.0 if math.isnan(sub) else sub, self.ap.airframe
        )
        if mode is None:
            raise Denied(f"mode {main:g}/{sub:g} not available")
        res = self.ap.set_mode(mode, mode_source(cmd.sender[1]))
        if res.ok and self.personality is Personality.ARDUPILOT:
            self.mode_number, self.guided_hover = int(main), False  # the heartbeat shows it
        return res, None

    def _reposition(self, cmd: Cmd):
        home = self.ap.home
        s = self.ap.state
        lat, lon, z = cmd.p[4], cmd.p[5], cmd.p[6]
        yaw = cmd.p[3]
        if math.isinf(lat) or math.isinf(lon) or math.isinf(z) or math.isinf(yaw):
            raise Denied("position not finite")
        pos = np.array(s.pos_ned, dtype=float)
        if not (math.isnan(lat) or math.isnan(lon)):
            if not (-90 <= lat <= 90 and -180 <= lon <= 180):
                raise Denied("latitude/longitude out of range")
            pos[:2] = geodetic_to_ned(home, lat, lon, home.alt_m)[:2]
        if not math.isnan(z):
            rel = cmd.frame in (
                M.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            )
            pos[2] = -z if rel else home.alt_m - z
        if np.linalg.norm(pos[:2]) > MAX_RANGE_M or not -MAX_ALTITUDE_M <= pos[2] <= 1.0:
            raise Denied("reposition target out of range")
        return self.ap.reposition(pos, None if math.isnan(yaw) else yaw), None

    def _mission_start(self, cmd: Cmd):
        self.guided_hover = False
        first = cmd.p[0]
        n = self.mission_count()
        if n == 0:
            return Result.denied("no mission uploaded"), None
        if not math.isnan(first) and first != 0.0:
            seq = _int_param(first, 0, n - 1, "first item")
            res = self.ap.set_mission_current(seq)
            if not res.ok:
                return res, None
        return self.ap.set_mode(FlightMode.MISSION), None

    def _set_mission_current(self, cmd: Cmd):
        n = self.mission_count()
        seq = _int_param(cmd.p[0], 0, max(n - 1, 0), "mission item")
        return self.ap.set_mission_current(seq), None

    def _ack(self, cmd: Cmd, result: int):
        return self.mav.command_ack_encode(cmd.command, result, 0, 0, *cmd.sender)


_SERVICE_COMMANDS = {
    M.MAV_CMD_SET_MESSAGE_INTERVAL,
    M.MAV_CMD_GET_MESSAGE_INTERVAL,
    M.MAV_CMD_REQUEST_MESSAGE,
    M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
}


def mode_source(component: int) -> ModeSource:
    """Whose mode change a sender's is: an onboard computer's is a companion's."""
    return ModeSource.COMPANION if component in ONBOARD_COMPONENTS else ModeSource.USER


def refusal_result(res: Result) -> int:
    """The MAV_RESULT of an autopilot's refusal: for now, or for good."""
    return M.MAV_RESULT_TEMPORARILY_REJECTED if res.temporary else M.MAV_RESULT_DENIED


def _check_params(cmd: Cmd) -> None:
    """Checks common to every handled command, before any handler runs (raises Denied).

    No parameter may be infinite. Commands with a position (TAKEOFF, LAND, REPOSITION) need
    latitude in [-90, 90], longitude in [-180, 180], |altitude| <= MAX_ABS_ALT_M and
    |yaw| <= MAX_ABS_YAW, or NaN ("current", as the spec gives it)."""
    for i, v in enumerate(cmd.p):
        if math.isinf(v):
            raise Denied(f"param{i + 1} is infinite")
    if cmd.command in _POSITIONAL:
        yaw, lat, lon, alt = cmd.p[3], cmd.p[4], cmd.p[5], cmd.p[6]
        if not (math.isnan(lat) or -90.0 <= lat <= 90.0):
            raise Denied(f"latitude {lat:.6g} out of range [-90, 90]")
        if not (math.isnan(lon) or -180.0 <= lon <= 180.0):
            raise Denied(f"longitude {lon:.6g} out of range [-180, 180]")
        if not (math.isnan(alt) or abs(alt) <= MAX_ABS_ALT_M):
            raise Denied(f"altitude {alt:.6g} m out of range")
        if not (math.isnan(yaw) or abs(yaw) <= MAX_ABS_YAW):
            raise Denied(f"yaw {yaw:.6g} out of range")


def _check_heartbeat_interval(msg_id: int, interval_us: float) -> None:
    """Every client on a link relies on HEARTBEAT for link-loss detection: one client may not
    stop it (interval -1) or slow it below MIN_HEARTBEAT_HZ for all of them."""
    if msg_id != M.MAVLINK_MSG_ID_HEARTBEAT or interval_us == 0:
        return
    if interval_us < 0 or interval_us > 1e6 / MIN_HEARTBEAT_HZ:
        raise Denied(f"HEARTBEAT cannot be stopped or slowed below {MIN_HEARTBEAT_HZ:g} Hz")


def _int_param(v: float, lo: int, hi: int, what: str) -> int:
    if not (math.isfinite(v) and float(v).is_integer() and lo <= v <= hi):
        raise Denied(f"{what} must be an integer in [{lo}, {hi}]")
    return int(v)


def _same(a: tuple, b: tuple) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b))
