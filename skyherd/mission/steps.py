"""The phases every mission shares, as generators stepped once per tick.

A phase reads like the blocking script it replaces — arm, take off, wait for the altitude —
but each `yield` ends the tick: the companion sends what the phase queued, closes the tick,
and the next call resumes with the telemetry of the next tick. Timeouts count tick time
(simulation time in lockstep, the autopilot's time when free-running), so a phase takes the
same number of ticks at any speed-up and any machine load.

    def mission(v):
        yield from wait_ready(v)
        yield from arm(v)
        yield from takeoff(v, 10.0)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Generator

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink.modes import Personality, custom_mode_of
from skyherd.hil.autopilots import MODE_REPORT_HZ
from skyherd.mission.vehicle import VehicleLink

M = mavlink2
Phase = Generator[None, None, None]

STATUSTEXT_WAIT_S = 0.3  # a refused command's reason arrives ~100 ms after its ACK (PX4)


class MissionError(Exception):
    """A phase could not be completed; the message says what was seen."""


class CommandRefused(MissionError):
    def __init__(self, command: int, result: int | None, reason: str = ""):
        cmd = M.enums["MAV_CMD"].get(command)
        name = cmd.name if cmd else str(command)
        res = "no answer" if result is None else M.enums["MAV_RESULT"][result].name
        super().__init__(
            f"{name} failed: {res}" + (f" — the autopilot says: {reason}" if reason else "")
        )
        self.command, self.result = command, result


def wait_until(v: VehicleLink, predicate: Callable[[], bool], timeout_s: float, what: str) -> Phase:
    """Yield ticks until `predicate()` holds; MissionError after `timeout_s` of tick time."""
    t0 = v.t
    while not predicate():
        if v.t - t0 > timeout_s:
            raise MissionError(f"timed out after {timeout_s:.0f} s waiting for {what}")
        yield


def wait_s(v: VehicleLink, seconds: float) -> Phase:
    t0 = v.t
    while v.t - t0 < seconds - 1e-9:
        yield


def command(
    v: VehicleLink, cmd: int, *params: float, retries: int = 3, retry_s: float = 1.5
) -> Phase:
    """COMMAND_LONG until acknowledged (confirmation counts up on each retry, as the protocol
    asks); a refusal raises CommandRefused with the autopilot's STATUSTEXT reason."""
    for confirmation in range(retries):
        v.acks.pop(cmd, None)
        n_text = len(v.tel.statustexts)
        v.command_long(cmd, params, confirmation)
        t0 = v.t
        while v.acks.get(cmd, M.MAV_RESULT_IN_PROGRESS) == M.MAV_RESULT_IN_PROGRESS:
            if v.t - t0 > retry_s:
                break
            yield
        else:
            result = v.acks[cmd]
            if result == M.MAV_RESULT_ACCEPTED:
                return
            yield from wait_s(v, STATUSTEXT_WAIT_S)
            reason = "; ".join(text for _, _, text in v.tel.statustexts[n_text:])
            raise CommandRefused(cmd, result, reason)
    raise CommandRefused(cmd, None)


def mode_params(v: VehicleLink, mode: FlightMode) -> tuple[float, ...]:
    """DO_SET_MODE params for `mode`: the autopilot's profile's (hil.autopilots), or the PX4 /
    ArduCopter numbers of flight.mavlink.modes before its heartbeat told which it is."""
    if v.profile is not None:
        return v.profile.set_mode_params(mode)
    personality = v.tel.personality
    packed = custom_mode_of(personality, mode)
    if personality is Personality.PX4:
        main, sub = (packed >> 16) & 0xFF, (packed >> 24) & 0xFF
    else:
        main, sub = packed, 0
    return (M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, main, sub)


def set_mode(v: VehicleLink, mode: FlightMode, timeout_s: float = 5.0) -> Phase:
    """DO_SET_MODE, then wait until the heartbeat shows the mode."""
    yield from command(v, M.MAV_CMD_DO_SET_MODE, *mode_params(v, mode))
    yield from wait_until(v, lambda: v.tel.mode is mode, timeout_s, f"mode {mode.name}")


def wait_ready(v: VehicleLink, timeout_s: float = 60.0) -> Phase:
    """A heartbeat, home and a local position (asks for HOME_POSITION every 2 s, and for the
    profile's streams: SET_MESSAGE_INTERVAL, or REQUEST_DATA_STREAM where older firmware
    answers that it does not support it)."""
    t_ask = -math.inf
    t0 = v.t
    on_wall = v.tel.time_boot_ms == 0  # free-running before any message: wall time counts
    while missing := not_ready(v):
        if on_wall and v.tel.time_boot_ms > 0:  # the tick clock became the autopilot's: a
            t0, on_wall = v.t, False  # second mission on a running PX4 starts at its uptime
        # the autopilot's own readiness time where it is longer (ArduCopter's EKF: ~40 s)
        limit = max(timeout_s, v.profile.ready_timeout_s if v.profile is not None else 0.0)
        if v.t - t0 > limit:
            raise MissionError(
                f"timed out after {limit:.0f} s waiting for {', '.join(missing)}: is the "
                "vehicle running and its link address right?"
            )
        if v.target_system is not None and v.t - t_ask >= 2.0:
            v.command_long(M.MAV_CMD_REQUEST_MESSAGE, (M.MAVLINK_MSG_ID_HOME_POSITION,), 0)
            if v.profile is not None:  # ArduPilot streams nothing it is not asked for
                for msg_id, hz in v.profile.stream_requests():
                    v.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, (msg_id, 1e6 / hz), 0)
            if v.acks.get(M.MAV_CMD_SET_MESSAGE_INTERVAL) == M.MAV_RESULT_UNSUPPORTED:
                for stream_id, hz in v.profile.data_stream_requests():
                    v.send(M.MAVLink_request_data_stream_message(
                        v.target_system, 1, stream_id, round(hz), 1))  # fmt: skip
            t_ask = v.t
        yield
    if v.unknown_autopilot:
        raise MissionError(v.unknown_autopilot)


def not_ready(v: VehicleLink) -> list[str]:
    """What a mission still waits for before it may fly (empty: ready)."""
    tel, out = v.tel, []
    if tel.mode is None:
        out.append("a heartbeat")
    if not tel.home_ok:
        out.append("home (HOME_POSITION)")
    if tel.pos_ned is None:
        out.append("a local position (LOCAL_POSITION_NED)")
    if tel.quat is None:
        out.append("an attitude")
    return out


UNREAD_STREAMS = ("ATTITUDE", "GLOBAL_POSITION_INT", "ALTITUDE", "VFR_HUD", "BATTERY_STATUS")
"""Streams a mission does not read: the attitude comes as ATTITUDE_QUATERNION, the position as
LOCAL_POSITION_NED (45 of the 77 messages a second PX4 sends on its onboard link)."""


def quiet_streams(v: VehicleLink, names: tuple[str, ...] = UNREAD_STREAMS) -> None:
    """SET_MESSAGE_INTERVAL(−1) for `names` on the companion's link (the autopilot applies it to
    the link that asked, as PX4 does; a ground station's link keeps its rates). With K links
    the parsing of unread telemetry is the companion's largest cost."""
    for name in names:
        v.command_long(
            M.MAV_CMD_SET_MESSAGE_INTERVAL, (getattr(M, f"MAVLINK_MSG_ID_{name}"), -1), 0
        )


def report_modes(v: VehicleLink, hz: float = MODE_REPORT_HZ) -> None:
    """SET_MESSAGE_INTERVAL(HEARTBEAT) at `hz` on the companion's link (hil.autopilots.
    MODE_REPORT_HZ: every mode change seen within a tick)."""
    v.command_long(M.MAV_CMD_SET_MESSAGE_INTERVAL, (M.MAVLINK_MSG_ID_HEARTBEAT, 1e6 / hz), 0)


def arm(v: VehicleLink, timeout_s: float = 30.0) -> Phase:
    yield from wait_until(v, lambda: v.tel.landed_state == M.MAV_LANDED_STATE_ON_GROUND,
                          timeout_s, "the vehicle on the ground")  # fmt: skip
    yield from command(v, M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0)
    yield from wait_until(v, lambda: v.tel.armed, 5.0, "armed")


def takeoff(v: VehicleLink, altitude_m: float, timeout_s: float = 60.0) -> Phase:
    """NAV_TAKEOFF (PX4 reads param 7 as AMSL), then wait until within 0.5 m of `altitude_m`."""
    nan = math.nan
    yield from command(v, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, nan, nan, nan, altitude_m + v.home_amsl_m)
    yield from wait_until(v, lambda: v.tel.pos_ned is not None and -v.tel.pos_ned[2] > altitude_m - 0.5,
                          timeout_s, f"altitude {altitude_m:.0f} m")  # fmt: skip


def land(v: VehicleLink, timeout_s: float = 120.0, stop_stream: bool = True) -> Phase:
    """NAV_LAND, then wait for the disarm. The setpoint stream stops once the landing is
    accepted: a stream still running when PX4 disarms puts it back in OFFBOARD, and the next
    arm is TEMPORARILY_REJECTED."""
    nan = math.nan
    yield from command(v, M.MAV_CMD_NAV_LAND, 0, 0, 0, nan, nan, nan, nan)
    if stop_stream:
        v.setpoint = None
    yield from wait_until(v, lambda: not v.tel.armed, timeout_s, "landing and disarm")


def recipe(v: VehicleLink, steps, hold=None) -> Phase:
    """Run an autopilot profile's recipe (hil.autopilots.Step): its take-off, hand-over or
    landing, in the order and with the retries that autopilot needs. `hold()` gives the
    position-hold setpoint a "stream_setpoints" step streams."""
    from skyherd.flight.autopilot_api import Setpoint

    for st in steps:
        k = st.kind
        if k == "wait_on_ground":
            yield from wait_until(v, lambda: v.tel.landed_state == M.MAV_LANDED_STATE_ON_GROUND,
                                  30.0, st.what)  # fmt: skip
        elif k == "stream_setpoints":
            p = v.tel.pos_ned
            v.setpoint = hold() if hold is not None else Setpoint(pos_ned=p.copy(), yaw=0.0)
            yield from wait_s(v, st.params[0] if st.params else 0.0)
        elif k == "stop_setpoints":
            v.setpoint = None
        elif k == "set_mode":
            yield from _retrying(v, st, lambda st=st: set_mode(v, st.mode))
        elif k == "arm":
            yield from _retrying(v, st, lambda: _arm(v))
        elif k == "command":
            yield from _retrying(v, st, lambda st=st: command(v, st.command, *st.params))
        elif k == "wait_altitude":
            yield from wait_until(v, lambda st=st: v.tel.pos_ned is not None
                                  and -v.tel.pos_ned[2] > st.altitude_m, 120.0, st.what)  # fmt: skip
        elif k == "wait_disarmed":
            yield from wait_until(v, lambda: not v.tel.armed, 240.0, st.what)
        elif k == "set_param":
            _set_param(v, st.what, st.params[0])
            yield
        else:
            raise MissionError(f"unknown recipe step {k!r} ({st.what})")


def _retrying(v: VehicleLink, st, make) -> Phase:
    for attempt in range(max(1, st.retries)):
        try:
            yield from make()
            return
        except CommandRefused:
            if attempt + 1 >= max(1, st.retries):
                raise
            yield from wait_s(v, st.retry_s)


def _arm(v: VehicleLink) -> Phase:
    yield from command(v, M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 0)
    yield from wait_until(v, lambda: v.tel.armed, 5.0, "armed")


def set_param_checked(v: VehicleLink, name: str, value: float, tries: int = 3,
                      wait_s: float = 1.0) -> Phase:  # fmt: skip
    """PARAM_SET until the PARAM_VALUE echo shows it (`tries` times, `wait_s` of the
    autopilot's time apart); a MissionError when it never does."""
    for _ in range(tries):
        v.params.pop(name, None)
        _set_param(v, name, value)
        t0 = v.t
        while v.t - t0 < wait_s:
            got = v.params.get(name)
            if got is not None and abs(got - value) <= 1e-3 * max(1.0, abs(value)):
                return
            yield
    raise MissionError(f"the autopilot did not take {name} = {value:g}")


def _set_param(v: VehicleLink, name: str, value: float) -> None:
    v.send(M.MAVLink_param_set_message(v.target_system or 1, 1, name.encode("ascii"), float(value),
                                       M.MAV_PARAM_TYPE_REAL32))  # fmt: skip


def read_params(v: VehicleLink, timeout_s: float = 20.0) -> Phase:
    """PARAM_REQUEST_LIST, then wait until every parameter has come (or `timeout_s`: what came
    is what the companion knows; an absent parameter is not checked)."""
    v.param_updates.clear()
    v.send(M.MAVLink_param_request_list_message(v.target_system or 1, 1))
    t0 = v.t
    while v.param_count is None or len(v.params) < v.param_count:
        if v.t - t0 > timeout_s:
            return
        yield
