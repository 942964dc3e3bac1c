"""What differs between the autopilots skyherd's companion flies: PX4, ArduCopter, ArduPlane.

One frozen profile per autopilot, found from the HEARTBEAT (its `autopilot` field and vehicle
`type`). A profile answers small pure questions — what a
`custom_mode` means, which DO_SET_MODE parameters ask for a mode, which messages to request,
which parameter names hold a setting — and gives the take-off, hand-over, landing and end of a
mission as declarative recipes (`Step`s) that the companion executes (mission/steps.py
`recipe`, one tick at a time).

Facts each recipe follows (measured against real SITL builds, ../shared/PROTOCOLS.md):
- PX4 reads NAV_TAKEOFF param 7 as AMSL; it switches to OFFBOARD only while setpoints are
  streaming, and a stream still running when the landing ends puts it back in OFFBOARD disarmed
  (the next arm is TEMPORARILY_REJECTED): stop streaming once the landing is accepted. Land by
  DO_SET_MODE AUTO.LAND; PX4 1.17 SIH still put itself back in OFFBOARD when it disarmed after
  the landing (measured here, with the stream stopped 20 s before): the end switches it to Hold,
  and the next mission arms.
- ArduCopter takes off in GUIDED: the mode first, then arm (the first attempt may be refused
  while its gyros settle: retry), then NAV_TAKEOFF with param 7 above home. Its LOITER and
  ALT_HOLD read the pilot's throttle — with no RC the copter sinks — so its fallback is BRAKE.
- ArduPlane refuses NAV_TAKEOFF as COMMAND_LONG (quadplanes only): it takes off in TAKEOFF mode
  (13) to TKOFF_ALT, and holds position in LOITER. It accepts positions in GUIDED as
  DO_REPOSITION (COMMAND_INT, global frame) only; SET_POSITION_TARGET_LOCAL_NED moves only its
  altitude. It has no LAND mode (it lands at the end of an AUTO mission).
- ArduPilot streams nothing unasked on a fresh link and sends neither ATTITUDE_QUATERNION nor
  EXTENDED_SYS_STATE by default: attitude comes from ATTITUDE, the landed state from the armed
  flag, HEARTBEAT system_status and the altitude above home.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink.modes import COPTER, PLANE, PX4_AUTO_SUB, PX4_MAIN, Personality

M = mavlink2
NAN = math.nan

# MAVLink component id of skyherd's companion beside an autopilot (CONVENTIONS.md).


class UnsupportedMode(ValueError):
    """The autopilot has no mode for this FlightMode (the message says why, in one line)."""


class UnknownAutopilot(ValueError):
    """The HEARTBEAT names an autopilot or vehicle type skyherd cannot fly."""


@dataclass(frozen=True)
class Step:
    """One step of a recipe, executed in order by a client.

    kind: "wait_on_ground" | "set_param" (`what` = name, params = (value,)) | "stream_setpoints"
      (start holding the current position; params = (seconds of stream before the next step,))
      | "stop_setpoints" | "set_mode" | "arm" | "command" (COMMAND_LONG `command` with `params`;
      `mode`: the mode the command puts the vehicle in, if any)
      | "wait_altitude" (until `altitude_m` above home) | "wait_disarmed".
    retries / retry_s: attempts and the pause [s, vehicle time] between refused attempts.
    """

    kind: str
    mode: FlightMode | None = None
    command: int = 0
    params: tuple[float, ...] = ()
    retries: int = 1
    retry_s: float = 0.0
    altitude_m: float = 0.0
    what: str = ""


@dataclass(frozen=True)
class ParamNames:
    """Names (and the factor to SI) of the parameters a companion reads, per autopilot.
    An empty name: the autopilot has no such parameter."""

    offboard_loss_timeout: tuple[str, float] = ("", 1.0)  # [s]
    speed_max_xy: tuple[str, float] = ("", 1.0)  # [m/s]
    speed_max_up: tuple[str, float] = ("", 1.0)  # [m/s]
    speed_max_down: tuple[str, float] = ("", 1.0)  # [m/s]
    loiter_radius: tuple[str, float] = ("", 1.0)  # [m]
    airspeed_trim: tuple[str, float] = ("", 1.0)  # [m/s]
    bank_limit: tuple[str, float] = ("", 1.0)  # [rad]
    takeoff_altitude: tuple[str, float] = ("", 1.0)  # [m]
    fence_enable: tuple[str, float] = ("", 1.0)
    integers: frozenset[str] = frozenset()  # names the autopilot stores as integers


_DEG = math.pi / 180.0

PX4_PARAMS = ParamNames(
    offboard_loss_timeout=("COM_OF_LOSS_T", 1.0),
    speed_max_xy=("MPC_XY_VEL_MAX", 1.0),
    speed_max_up=("MPC_Z_VEL_MAX_UP", 1.0),
    speed_max_down=("MPC_Z_VEL_MAX_DN", 1.0),
    loiter_radius=("NAV_LOITER_RAD", 1.0),
    airspeed_trim=("FW_AIRSPD_TRIM", 1.0),
    bank_limit=("FW_R_LIM", _DEG),
    takeoff_altitude=("MIS_TAKEOFF_ALT", 1.0),
    fence_enable=("GF_ACTION", 1.0),
)
COPTER_PARAMS = ParamNames(
    offboard_loss_timeout=("GUID_TIMEOUT", 1.0),  # velocity/acceleration targets only
    speed_max_xy=("WPNAV_SPEED", 0.01),  # cm/s
    speed_max_up=("WPNAV_SPEED_UP", 0.01),
    speed_max_down=("WPNAV_SPEED_DN", 0.01),
    loiter_radius=("CIRCLE_RADIUS", 0.01),
    takeoff_altitude=("PILOT_TKOFF_ALT", 0.01),
    fence_enable=("FENCE_ENABLE", 1.0),
)
PLANE_PARAMS = ParamNames(  # ArduPlane 4.5+ names (read from its Parameters.cpp)
    loiter_radius=("WP_LOITER_RAD", 1.0),
    airspeed_trim=("AIRSPEED_CRUISE", 1.0),  # TRIM_ARSPD_CM [cm/s] before ArduPlane 4.5
    bank_limit=("ROLL_LIMIT_DEG", _DEG),  # LIM_ROLL_CD [cdeg] before 4.5
    speed_max_xy=("AIRSPEED_MAX", 1.0),
    speed_max_up=("TECS_CLMB_MAX", 1.0),  # its height controller's climb and sink limits
    speed_max_down=("TECS_SINK_MAX", 1.0),
    takeoff_altitude=("TKOFF_ALT", 1.0),
    fence_enable=("FENCE_ENABLE", 1.0),
    integers=frozenset({"WP_LOITER_RAD", "TKOFF_ALT"}),  # AP_Int16: 123.6 is stored as 123
)

# (number, autopilot's name, FlightMode it is read as or None). LOITER and ALT_HOLD read the
# pilot's sticks and throttle: they decode as the PX4 pilot modes, never as HOLD.
_COPTER_TABLE: tuple[tuple[int, str, FlightMode | None], ...] = (
    (COPTER["STABILIZE"], "STABILIZE", FlightMode.STABILIZED),
    (COPTER["ACRO"], "ACRO", FlightMode.MANUAL),
    (COPTER["ALT_HOLD"], "ALT_HOLD", FlightMode.ALTCTL),
    (COPTER["AUTO"], "AUTO", FlightMode.MISSION),
    (COPTER["GUIDED"], "GUIDED", FlightMode.OFFBOARD),
    (COPTER["LOITER"], "LOITER", FlightMode.POSCTL),
    (COPTER["RTL"], "RTL", FlightMode.RTL),
    (7, "CIRCLE", None),
    (COPTER["LAND"], "LAND", FlightMode.LAND),
    (11, "DRIFT", None),
    (13, "SPORT", None),
    (14, "FLIP", None),
    (15, "AUTOTUNE", None),
    (COPTER["POSHOLD"], "POSHOLD", FlightMode.POSCTL),
    (COPTER["BRAKE"], "BRAKE", FlightMode.HOLD),
    (18, "THROW", None),
    (19, "AVOID_ADSB", None),
    (20, "GUIDED_NOGPS", None),
    (21, "SMART_RTL", FlightMode.RTL),
    (22, "FLOWHOLD", None),
    (23, "FOLLOW", None),
    (24, "ZIGZAG", None),
    (25, "SYSTEMID", None),
    (26, "AUTOROTATE", None),
    (27, "AUTO_RTL", FlightMode.RTL),
    (28, "TURTLE", None),
)
_COPTER_SET: tuple[tuple[FlightMode, int], ...] = (
    (FlightMode.OFFBOARD, COPTER["GUIDED"]),
    (FlightMode.HOLD, COPTER["BRAKE"]),
    (FlightMode.RTL, COPTER["RTL"]),
    (FlightMode.LAND, COPTER["LAND"]),
    (FlightMode.MISSION, COPTER["AUTO"]),
    (FlightMode.POSCTL, COPTER["LOITER"]),
    (FlightMode.ALTCTL, COPTER["ALT_HOLD"]),
    (FlightMode.STABILIZED, COPTER["STABILIZE"]),
    (FlightMode.MANUAL, COPTER["ACRO"]),
    (FlightMode.TAKEOFF, COPTER["GUIDED"]),  # ArduCopter takes off in GUIDED (NAV_TAKEOFF)
)

_PLANE_TABLE: tuple[tuple[int, str, FlightMode | None], ...] = (
    (PLANE["MANUAL"], "MANUAL", FlightMode.MANUAL),
    (PLANE["CIRCLE"], "CIRCLE", FlightMode.HOLD),
    (PLANE["STABILIZE"], "STABILIZE", FlightMode.STABILIZED),
    (3, "TRAINING", None),
    (4, "ACRO", None),
    (5, "FBWA", FlightMode.STABILIZED),
    (PLANE["FBWB"], "FBWB", FlightMode.ALTCTL),
    (PLANE["CRUISE"], "CRUISE", FlightMode.POSCTL),
    (8, "AUTOTUNE", None),
    (PLANE["AUTO"], "AUTO", FlightMode.MISSION),
    (PLANE["RTL"], "RTL", FlightMode.RTL),
    (PLANE["LOITER"], "LOITER", FlightMode.HOLD),
    (PLANE["TAKEOFF"], "TAKEOFF", FlightMode.TAKEOFF),
    (14, "AVOID_ADSB", None),
    (PLANE["GUIDED"], "GUIDED", FlightMode.OFFBOARD),
    (17, "QSTABILIZE", None),
    (18, "QHOVER", None),
    (19, "QLOITER", None),
    (20, "QLAND", FlightMode.LAND),
    (21, "QRTL", FlightMode.RTL),
    (22, "QAUTOTUNE", None),
    (23, "QACRO", None),
    (24, "THERMAL", None),
    (25, "LOITER_ALT_QLAND", None),
)
_PLANE_SET: tuple[tuple[FlightMode, int], ...] = (
    (FlightMode.OFFBOARD, PLANE["GUIDED"]),
    (FlightMode.HOLD, PLANE["LOITER"]),
    (FlightMode.RTL, PLANE["RTL"]),
    (FlightMode.MISSION, PLANE["AUTO"]),
    (FlightMode.TAKEOFF, PLANE["TAKEOFF"]),
    (FlightMode.POSCTL, PLANE["CRUISE"]),
    (FlightMode.ALTCTL, PLANE["FBWB"]),
    (FlightMode.STABILIZED, PLANE["STABILIZE"]),
    (FlightMode.MANUAL, PLANE["MANUAL"]),
)

_PX4_SET: tuple[tuple[FlightMode, tuple[int, int]], ...] = (
    (FlightMode.MANUAL, (PX4_MAIN["MANUAL"], 0)),
    (FlightMode.STABILIZED, (PX4_MAIN["STABILIZED"], 0)),
    (FlightMode.ALTCTL, (PX4_MAIN["ALTCTL"], 0)),
    (FlightMode.POSCTL, (PX4_MAIN["POSCTL"], 0)),
    (FlightMode.OFFBOARD, (PX4_MAIN["OFFBOARD"], 0)),
    (FlightMode.HOLD, (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"])),
    (FlightMode.TAKEOFF, (PX4_MAIN["AUTO"], PX4_AUTO_SUB["TAKEOFF"])),
    (FlightMode.MISSION, (PX4_MAIN["AUTO"], PX4_AUTO_SUB["MISSION"])),
    (FlightMode.RTL, (PX4_MAIN["AUTO"], PX4_AUTO_SUB["RTL"])),
    (FlightMode.LAND, (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LAND"])),
)
_PX4_AUTO_NAMES = {v: k for k, v in PX4_AUTO_SUB.items()} | {7: "RTGS", 8: "FOLLOW_TARGET",
                                                              9: "PRECLAND", 10: "VTOL_TAKEOFF"}  # fmt: skip
_PX4_MAIN_NAMES = {v: k for k, v in PX4_MAIN.items()} | {8: "RATTITUDE", 9: "TERMINATION"}

MODE_REPORT_HZ = 20.0
"""The HEARTBEAT rate asked of an autopilot [Hz] (the companion: mission.steps.report_modes;
the followed world: world.follow): it is the one message that carries the mode and the arming,
and at its default 1 Hz a mode the autopilot chose by itself (a battery RTL) went unseen for up
to a second while the net asked for its own over it (found by the campaign through the mission
code, `skyherd drill --campaign`: battery drills). Twice the 10 Hz tick: every tick's telemetry
shows the mode of that instant. PX4 and ArduPilot honour SET_MESSAGE_INTERVAL for HEARTBEAT; an
autopilot that refuses leaves it at 1 Hz."""

MSG = {
    "HEARTBEAT": M.MAVLINK_MSG_ID_HEARTBEAT,
    "SYS_STATUS": M.MAVLINK_MSG_ID_SYS_STATUS,
    "GPS_RAW_INT": M.MAVLINK_MSG_ID_GPS_RAW_INT,
    "ATTITUDE": M.MAVLINK_MSG_ID_ATTITUDE,
    "ATTITUDE_QUATERNION": M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    "LOCAL_POSITION_NED": M.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    "GLOBAL_POSITION_INT": M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
    "HOME_POSITION": M.MAVLINK_MSG_ID_HOME_POSITION,
    "EXTENDED_SYS_STATE": M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    "EKF_STATUS_REPORT": M.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
    "AUTOPILOT_VERSION": M.MAVLINK_MSG_ID_AUTOPILOT_VERSION,
}

# LOCAL_POSITION_NED and attitude [Hz]: one setpoint per position sample, so >= 10 Hz. PX4 (and
# the built-in vehicle) keep the interval exactly; ArduPilot is asked for a little more.
POSITION_RATE_HZ = 10.0

MULTIROTOR_TYPES = frozenset({
    M.MAV_TYPE_QUADROTOR, M.MAV_TYPE_HEXAROTOR, M.MAV_TYPE_OCTOROTOR, M.MAV_TYPE_TRICOPTER,
    M.MAV_TYPE_COAXIAL, M.MAV_TYPE_HELICOPTER, M.MAV_TYPE_DODECAROTOR, M.MAV_TYPE_DECAROTOR,
})  # fmt: skip
FIXEDWING_TYPES = frozenset({
    M.MAV_TYPE_FIXED_WING, M.MAV_TYPE_VTOL_DUOROTOR, M.MAV_TYPE_VTOL_QUADROTOR,
    M.MAV_TYPE_VTOL_TILTROTOR, M.MAV_TYPE_VTOL_GYRODYNE,
})  # fmt: skip


@dataclass(frozen=True)
class AutopilotProfile:
    """What a companion must know about one autopilot (base: behaviour common to all)."""

    name: str
    personality: Personality
    vehicle: str  # "multirotor" | "fixedwing"
    params: ParamNames
    ai_mode: FlightMode = FlightMode.OFFBOARD  # the mode the AI flies in
    fallback_mode: FlightMode = FlightMode.HOLD  # position hold with no pilot
    # the documented end of a mission that lands: None = landed and disarmed; else the vehicle
    # is left armed in the air in this mode (ArduPlane: RTL, it has no LAND mode)
    end_mode: FlightMode | None = None
    version: str = ""  # from AUTOPILOT_VERSION, e.g. "4.7.0"
    ready_timeout_s: float = 120.0  # [s autopilot time] for heartbeat, position and home
    position_rate_hz: float = 12.5  # LOCAL_POSITION_NED / attitude stream [Hz]
    setpoint_frame: str = "local_ned"  # "local_ned" | "reposition" (DO_REPOSITION, global)
    setpoint_min_interval_s: float = 0.0  # [s] between setpoints (0: one per position sample)
    reposition_frame: int = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    reposition_lead_s: float = 5.0  # a velocity setpoint → a DO_REPOSITION this far ahead [s]
    landed_from_extended_sys_state: bool = False
    # its loiter flies radius · EAS2TAS² (ArduPlane's L1 loiter_radius() with NAVL1_LIM_BANK 0):
    # a companion that wants radius R sets R / EAS2TAS² (`loiter_radius_setting`)
    loiter_tas_scaled: bool = False
    # its loiter about a moving centre runs wide of the set radius: trim it in flight
    loiter_radius_trim: bool = False
    attitude_message: str = "ATTITUDE"
    mode_table: tuple = field(default=(), repr=False)
    set_table: tuple = field(default=(), repr=False)

    # ---- modes -----------------------------------------------------------------------------
    def decode_mode(self, custom_mode: int) -> FlightMode | None:
        """The FlightMode a HEARTBEAT `custom_mode` means (None: a mode skyherd does not fly)."""
        for number, _, mode in self.mode_table:
            if number == custom_mode:
                return mode
        return None

    def mode_name(self, custom_mode: int) -> str:
        """The autopilot's own name for a `custom_mode` (as its ground station shows it)."""
        for number, name, _ in self.mode_table:
            if number == custom_mode:
                return name
        return f"mode {custom_mode}"

    def custom_mode(self, mode: FlightMode) -> int:
        for m, number in self.set_table:
            if m is mode:
                return number
        raise UnsupportedMode(f"{self.name} has no mode for {mode.name}")

    def set_mode_params(self, mode: FlightMode) -> tuple[float, ...]:
        """DO_SET_MODE params 1-3: custom-mode flag, then the mode number (ArduPilot)."""
        return (float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(self.custom_mode(mode)), 0.0)

    # ---- telemetry -------------------------------------------------------------------------
    def stream_requests(self) -> tuple[tuple[int, float], ...]:
        """(message id, rate [Hz]) to ask for with SET_MESSAGE_INTERVAL; the HEARTBEAT (the
        one message that carries the mode and the arming) at MODE_REPORT_HZ."""
        return (
            (MSG["HEARTBEAT"], MODE_REPORT_HZ),
            (MSG["LOCAL_POSITION_NED"], self.position_rate_hz),
            (MSG[self.attitude_message], self.position_rate_hz),
            (MSG["GLOBAL_POSITION_INT"], 5.0),
            (MSG["SYS_STATUS"], 2.0),
            (MSG["GPS_RAW_INT"], 2.0),
            (MSG["HOME_POSITION"], 0.5),
        )

    def data_stream_requests(self) -> tuple[tuple[int, float], ...]:
        """(MAV_DATA_STREAM, rate [Hz]) for REQUEST_DATA_STREAM, when SET_MESSAGE_INTERVAL is
        not answered (older firmware)."""
        return (
            (M.MAV_DATA_STREAM_POSITION, self.position_rate_hz),  # LOCAL/GLOBAL_POSITION
            (M.MAV_DATA_STREAM_EXTRA1, self.position_rate_hz),  # ATTITUDE
            (M.MAV_DATA_STREAM_EXTENDED_STATUS, 2.0),  # SYS_STATUS, GPS_RAW_INT, EKF status
        )

    def param_name(self, key: str) -> str:
        """The autopilot's name of a ParamNames field (UnsupportedMode-like ValueError if none)."""
        name, _ = getattr(self.params, key)
        if not name:
            raise ValueError(f"{self.name} has no parameter for {key}")
        return name

    def param_to_si(self, key: str, value: float) -> float:
        return float(value) * getattr(self.params, key)[1]

    def loiter_radius_setting(self, radius_m: float, altitude_amsl_m: float) -> float:
        """The loiter-radius parameter [its unit] that makes the autopilot fly `radius_m` at
        `altitude_amsl_m` (ISA: EAS2TAS² = ρ0 / ρ(h), ρ / ρ0 = (1 − 2.25577e-5 h)^4.25588)."""
        r = float(radius_m)
        if self.loiter_tas_scaled:
            r *= (1.0 - 2.25577e-5 * float(altitude_amsl_m)) ** 4.25588
        return self.param_value("loiter_radius", r)

    def param_value(self, key: str, si_value: float) -> float:
        """The value to PARAM_SET for `si_value` of a ParamNames field: in the autopilot's unit,
        and rounded up to a whole number where it stores an integer (ArduPlane's WP_LOITER_RAD:
        a set value must read back as sent, and a wider circle stays within the turn)."""
        name, factor = getattr(self.params, key)
        value = float(si_value) / factor
        return float(math.ceil(value - 1e-9)) if name in self.params.integers else value

    # ---- recipes ---------------------------------------------------------------------------
    def takeoff_steps(self, alt_above_home_m: float, home_amsl_m: float) -> tuple[Step, ...]:
        raise NotImplementedError

    def handover_steps(self) -> tuple[Step, ...]:
        """From the take-off to the AI's mode: a hold setpoint streams before the switch."""
        return (
            Step("stream_setpoints", params=(1.0,), what="hold setpoints before the switch"),
            Step("set_mode", self.ai_mode, retries=3, retry_s=1.0, what=self._name(self.ai_mode)),
        )

    def land_steps(self) -> tuple[Step, ...]:
        raise NotImplementedError

    def end_steps(self) -> tuple[Step, ...]:
        """After the landing: leave the vehicle disarmed, in a mode the next mission starts from."""
        return (Step("stop_setpoints", what="stop the setpoint stream"),)

    def _name(self, mode: FlightMode) -> str:
        try:
            return f"{mode.name} ({self.mode_name(self.custom_mode(mode))})"
        except UnsupportedMode:
            return mode.name


@dataclass(frozen=True)
class Px4Profile(AutopilotProfile):
    """PX4: custom_mode = main << 16 | sub << 24; OFFBOARD needs the stream first."""

    name: str = "PX4"
    personality: Personality = Personality.PX4
    vehicle: str = "multirotor"
    params: ParamNames = PX4_PARAMS
    ready_timeout_s: float = 60.0
    position_rate_hz: float = POSITION_RATE_HZ
    landed_from_extended_sys_state: bool = True
    attitude_message: str = "ATTITUDE_QUATERNION"
    reposition_frame: int = M.MAV_FRAME_GLOBAL_INT  # PX4: DO_REPOSITION in GLOBAL_INT frames only

    def decode_mode(self, custom_mode: int) -> FlightMode | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        if main == PX4_MAIN["AUTO"] and sub == PX4_AUTO_SUB["READY"]:
            return FlightMode.HOLD
        if main == PX4_MAIN["AUTO"] and sub == 7:  # RTGS: return to ground station
            return FlightMode.RTL
        for mode, (m, s) in _PX4_SET:
            if (m, s) == (main, sub if main == PX4_MAIN["AUTO"] else 0):
                return mode
        return None

    def mode_name(self, custom_mode: int) -> str:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        name = _PX4_MAIN_NAMES.get(main, f"mode {main}")
        return f"AUTO.{_PX4_AUTO_NAMES.get(sub, sub)}" if name == "AUTO" else name

    def custom_mode(self, mode: FlightMode) -> int:
        for m, (main, sub) in _PX4_SET:
            if m is mode:
                return (main << 16) | (sub << 24)
        raise UnsupportedMode(f"PX4 has no mode for {mode.name}")

    def set_mode_params(self, mode: FlightMode) -> tuple[float, ...]:
        packed = self.custom_mode(mode)
        main, sub = (packed >> 16) & 0xFF, (packed >> 24) & 0xFF
        return (float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED), float(main), float(sub))

    def stream_requests(self) -> tuple[tuple[int, float], ...]:
        return super().stream_requests() + ((MSG["EXTENDED_SYS_STATE"], 2.0),)

    def takeoff_steps(self, alt_above_home_m: float, home_amsl_m: float) -> tuple[Step, ...]:
        a = float(alt_above_home_m)
        return (
            Step("wait_on_ground", what="the vehicle on the ground"),
            Step("arm", retries=3, retry_s=1.0, what="arm"),
            Step("command", command=M.MAV_CMD_NAV_TAKEOFF,
                 params=(0.0, 0.0, 0.0, NAN, NAN, NAN, a + float(home_amsl_m)),
                 what=f"NAV_TAKEOFF to {a:.0f} m (param 7 AMSL)"),
            Step("wait_altitude", altitude_m=a - 0.5, what=f"altitude {a:.0f} m"),
        )  # fmt: skip

    def land_steps(self) -> tuple[Step, ...]:
        return (
            # DO_SET_MODE AUTO.LAND (the mode a ground station would set); PX4 1.17 may still go
            # back to OFFBOARD once disarmed: end_steps() puts it in Hold
            Step("set_mode", FlightMode.LAND, retries=3, retry_s=1.0, what="AUTO.LAND"),
            Step("stop_setpoints", what="stop streaming before the landing ends"),
            Step("wait_disarmed", what="landing and disarm"),
        )  # fmt: skip

    def end_steps(self) -> tuple[Step, ...]:
        return (
            Step("stop_setpoints", what="stop the setpoint stream"),
            Step("set_mode", FlightMode.HOLD, retries=2, retry_s=1.0,
                 what="leave it in Hold (AUTO.LOITER), ready to arm again"),
        )  # fmt: skip


@dataclass(frozen=True)
class ArduCopterProfile(AutopilotProfile):
    """ArduCopter: GUIDED is the AI's mode, BRAKE its fallback; take-off in GUIDED."""

    name: str = "ArduCopter"
    personality: Personality = Personality.ARDUPILOT
    vehicle: str = "multirotor"
    params: ParamNames = COPTER_PARAMS
    mode_table: tuple = field(default=_COPTER_TABLE, repr=False)
    set_table: tuple = field(default=_COPTER_SET, repr=False)

    def stream_requests(self) -> tuple[tuple[int, float], ...]:
        return super().stream_requests() + ((MSG["EKF_STATUS_REPORT"], 2.0),)

    def takeoff_steps(self, alt_above_home_m: float, home_amsl_m: float) -> tuple[Step, ...]:
        a = float(alt_above_home_m)
        return (
            Step("wait_on_ground", what="the vehicle on the ground"),
            # ArduCopter ignores setpoints outside GUIDED; a PX4-like vehicle needs them first.
            Step("stream_setpoints", params=(0.5,), what="hold setpoints before GUIDED"),
            Step("set_mode", FlightMode.OFFBOARD, retries=3, retry_s=1.0, what="GUIDED"),
            # a position target sent after NAV_TAKEOFF would end GUIDED's take-off on the ground
            Step("stop_setpoints", what="no setpoints during the take-off"),
            Step("arm", retries=10, retry_s=2.0, what="arm (refused while the gyros settle)"),
            Step("command", command=M.MAV_CMD_NAV_TAKEOFF,
                 params=(0.0, 0.0, 0.0, NAN, 0.0, 0.0, a),
                 what=f"NAV_TAKEOFF to {a:.0f} m (param 7 above home)"),
            Step("wait_altitude", altitude_m=a - 0.5, what=f"altitude {a:.0f} m"),
        )  # fmt: skip

    def land_steps(self) -> tuple[Step, ...]:
        return (
            Step("set_mode", FlightMode.LAND, retries=3, retry_s=1.0, what="LAND"),
            Step("stop_setpoints", what="no setpoints in LAND"),
            Step("wait_disarmed", what="landing and disarm"),
        )


@dataclass(frozen=True)
class ArduPlaneProfile(AutopilotProfile):
    """ArduPlane: TAKEOFF mode, GUIDED with DO_REPOSITION, LOITER as the fallback."""

    name: str = "ArduPlane"
    personality: Personality = Personality.ARDUPILOT
    vehicle: str = "fixedwing"
    end_mode: FlightMode | None = FlightMode.RTL
    params: ParamNames = PLANE_PARAMS
    setpoint_frame: str = "reposition"
    setpoint_min_interval_s: float = 1.0  # each DO_REPOSITION is a new guided waypoint
    loiter_tas_scaled: bool = True
    loiter_radius_trim: bool = True

    mode_table: tuple = field(default=_PLANE_TABLE, repr=False)
    set_table: tuple = field(default=_PLANE_SET, repr=False)

    def stream_requests(self) -> tuple[tuple[int, float], ...]:
        return super().stream_requests() + ((MSG["EKF_STATUS_REPORT"], 2.0),)

    def takeoff_steps(self, alt_above_home_m: float, home_amsl_m: float) -> tuple[Step, ...]:
        a = float(alt_above_home_m)
        return (
            Step("set_param", params=(self.param_value("takeoff_altitude", a),), what="TKOFF_ALT"),
            Step("wait_on_ground", what="the aircraft on the ground"),
            Step("set_mode", FlightMode.TAKEOFF, retries=3, retry_s=1.0, what="TAKEOFF (13)"),
            Step("arm", retries=10, retry_s=2.0, what="arm (refused while the gyros settle)"),
            Step("wait_altitude", altitude_m=0.85 * a, what=f"climb towards {a:.0f} m"),
        )

    def handover_steps(self) -> tuple[Step, ...]:
        return (
            Step("set_mode", FlightMode.OFFBOARD, retries=3, retry_s=1.0, what="GUIDED"),
            Step("stream_setpoints", params=(0.0,), what="DO_REPOSITION targets"),
        )

    def land_steps(self) -> tuple[Step, ...]:
        return (
            Step("stop_setpoints", what="stop the DO_REPOSITION targets"),
            Step("set_mode", FlightMode.RTL, retries=3, retry_s=1.0,
                 what="RTL (ArduPlane has no LAND mode: it lands at the end of an AUTO mission)"),
        )  # fmt: skip


PX4 = Px4Profile()
ARDUCOPTER = ArduCopterProfile()
ARDUPLANE = ArduPlaneProfile()
PROFILES = {"px4": PX4, "arducopter": ARDUCOPTER, "arduplane": ARDUPLANE}


def detect(autopilot: int, mav_type: int) -> AutopilotProfile:
    """The profile for a HEARTBEAT's `autopilot` field and vehicle `type`."""
    if autopilot == M.MAV_AUTOPILOT_PX4:
        if mav_type in FIXEDWING_TYPES:
            return replace(PX4, vehicle="fixedwing")
        return PX4
    if autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA:
        if mav_type in FIXEDWING_TYPES:
            return ARDUPLANE
        if mav_type in MULTIROTOR_TYPES:
            return ARDUCOPTER
        kind = M.enums["MAV_TYPE"].get(mav_type)
        raise UnknownAutopilot(
            f"ArduPilot vehicle type {kind.name if kind else mav_type} is not flown by skyherd "
            "(ArduCopter and ArduPlane are)"
        )
    name = M.enums["MAV_AUTOPILOT"].get(autopilot)
    raise UnknownAutopilot(
        f"autopilot {name.name if name else autopilot} is not one skyherd flies (PX4, ArduPilot)"
    )
