"""Flight modes at the MAVLink boundary: PX4 custom modes or ArduCopter mode numbers.

PX4 packs `custom_mode = main_mode << 16 | sub_mode << 24` (px4_custom_mode.h) and sets
`base_mode` flags that ground stations use to decode it (pymavlink `interpret_px4_mode`).
ArduCopter puts its mode number in `custom_mode` directly.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink.config import Personality

# PX4 main modes and AUTO sub modes (px4_custom_mode.h).
PX4_MAIN = {
    "MANUAL": 1,
    "ALTCTL": 2,
    "POSCTL": 3,
    "AUTO": 4,
    "ACRO": 5,
    "OFFBOARD": 6,
    "STABILIZED": 7,
}
PX4_AUTO_SUB = {"READY": 1, "TAKEOFF": 2, "LOITER": 3, "MISSION": 4, "RTL": 5, "LAND": 6}

_PX4_OF_MODE: dict[FlightMode, tuple[int, int]] = {
    FlightMode.MANUAL: (PX4_MAIN["MANUAL"], 0),
    FlightMode.STABILIZED: (PX4_MAIN["STABILIZED"], 0),
    FlightMode.ALTCTL: (PX4_MAIN["ALTCTL"], 0),
    FlightMode.POSCTL: (PX4_MAIN["POSCTL"], 0),
    FlightMode.OFFBOARD: (PX4_MAIN["OFFBOARD"], 0),
    FlightMode.HOLD: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LOITER"]),
    FlightMode.TAKEOFF: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["TAKEOFF"]),
    FlightMode.MISSION: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["MISSION"]),
    FlightMode.RTL: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["RTL"]),
    FlightMode.LAND: (PX4_MAIN["AUTO"], PX4_AUTO_SUB["LAND"]),
}
_MODE_OF_PX4 = {v: k for k, v in _PX4_OF_MODE.items()}
_MODE_OF_PX4[(PX4_MAIN["AUTO"], PX4_AUTO_SUB["READY"])] = FlightMode.HOLD

# ArduCopter mode numbers (ArduCopter/mode.h).
COPTER = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "LAND": 9,
    "POSHOLD": 16,
    "BRAKE": 17,
}
_COPTER_OF_MODE: dict[FlightMode, int] = {
    FlightMode.MANUAL: COPTER["ACRO"],
    FlightMode.STABILIZED: COPTER["STABILIZE"],
    FlightMode.ALTCTL: COPTER["ALT_HOLD"],
    FlightMode.POSCTL: COPTER["POSHOLD"],
    FlightMode.HOLD: COPTER["BRAKE"],  # a hold with no pilot (LOITER reads the pilot's throttle)
    FlightMode.TAKEOFF: COPTER["GUIDED"],
    FlightMode.OFFBOARD: COPTER["GUIDED"],
    FlightMode.MISSION: COPTER["AUTO"],
    FlightMode.RTL: COPTER["RTL"],
    FlightMode.LAND: COPTER["LAND"],
}
_MODE_OF_COPTER = {
    COPTER["ACRO"]: FlightMode.MANUAL,
    COPTER["STABILIZE"]: FlightMode.STABILIZED,
    COPTER["ALT_HOLD"]: FlightMode.ALTCTL,
    COPTER["POSHOLD"]: FlightMode.POSCTL,
    COPTER["LOITER"]: FlightMode.HOLD,
    COPTER["BRAKE"]: FlightMode.HOLD,
    COPTER["GUIDED"]: FlightMode.OFFBOARD,
    COPTER["AUTO"]: FlightMode.MISSION,
    COPTER["RTL"]: FlightMode.RTL,
    COPTER["LAND"]: FlightMode.LAND,
}

# ArduPlane mode numbers (ArduPlane/mode.h), for a fixed-wing with the ardupilot personality.
# ArduPlane has no LAND mode (it lands in AUTO): LAND is shown as AUTO.
PLANE = {
    "MANUAL": 0,
    "CIRCLE": 1,
    "STABILIZE": 2,
    "FBWB": 6,
    "CRUISE": 7,
    "AUTO": 10,
    "RTL": 11,
    "LOITER": 12,
    "TAKEOFF": 13,
    "GUIDED": 15,
}
_PLANE_OF_MODE: dict[FlightMode, int] = {
    FlightMode.MANUAL: PLANE["MANUAL"],
    FlightMode.STABILIZED: PLANE["STABILIZE"],
    FlightMode.ALTCTL: PLANE["FBWB"],
    FlightMode.POSCTL: PLANE["CRUISE"],
    FlightMode.HOLD: PLANE["LOITER"],
    FlightMode.TAKEOFF: PLANE["TAKEOFF"],
    FlightMode.OFFBOARD: PLANE["GUIDED"],
    FlightMode.MISSION: PLANE["AUTO"],
    FlightMode.RTL: PLANE["RTL"],
    FlightMode.LAND: PLANE["AUTO"],
}
_MODE_OF_PLANE = {v: k for k, v in _PLANE_OF_MODE.items() if k is not FlightMode.LAND}
_MODE_OF_PLANE[PLANE["CIRCLE"]] = FlightMode.HOLD


def _apm_tables(airframe: str) -> tuple[dict, dict, dict]:
    """(mode → number, number → mode, name → number) for ArduCopter or ArduPlane."""
    if airframe == "fixedwing":
        return _PLANE_OF_MODE, _MODE_OF_PLANE, PLANE
    return _COPTER_OF_MODE, _MODE_OF_COPTER, COPTER


_MANUAL_MODES = {FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL}
_AUTO_MODES = {
    FlightMode.HOLD,
    FlightMode.TAKEOFF,
    FlightMode.MISSION,
    FlightMode.RTL,
    FlightMode.LAND,
}


def custom_mode_of(personality: Personality, mode: FlightMode, airframe: str = "quadrotor") -> int:
    """HEARTBEAT `custom_mode` for a flight mode (ArduPlane numbers for a fixed-wing)."""
    if personality is Personality.PX4:
        main, sub = _PX4_OF_MODE[mode]
        return (main << 16) | (sub << 24)
    return _apm_tables(airframe)[0][mode]


def base_mode_of(mode: FlightMode, armed: bool) -> int:
    """HEARTBEAT `base_mode` flags the way PX4 sets them (custom mode always enabled)."""
    f = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
    if armed:
        f |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
    if mode in _MANUAL_MODES:
        f |= mavlink.MAV_MODE_FLAG_MANUAL_INPUT_ENABLED
        if mode is not FlightMode.MANUAL:
            f |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    elif mode in _AUTO_MODES:
        f |= (
            mavlink.MAV_MODE_FLAG_AUTO_ENABLED
            | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
            | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        )
    else:  # OFFBOARD
        f |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED | mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
    return f


def mode_of_custom(
    personality: Personality, custom_main: float, custom_sub: float, airframe: str = "quadrotor"
) -> FlightMode | None:
    """Flight mode asked for by DO_SET_MODE params 2 and 3 (or SET_MODE's custom_mode).

    PX4: param2 main mode, param3 sub mode. ArduPilot: param2 the mode number.
    None when the numbers name no mode this vehicle has.
    """
    if personality is Personality.PX4:
        if not (_is_small_int(custom_main) and _is_small_int(custom_sub)):
            return None
        return _MODE_OF_PX4.get((int(custom_main), int(custom_sub)))
    if not _is_small_int(custom_main):
        return None
    return _apm_tables(airframe)[1].get(int(custom_main))


def mode_of_packed(
    personality: Personality, custom_mode: int, airframe: str = "quadrotor"
) -> FlightMode | None:
    """Flight mode from a packed 32-bit `custom_mode` (SET_MODE message)."""
    if personality is Personality.PX4:
        return mode_of_custom(personality, (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)
    return mode_of_custom(personality, custom_mode, 0, airframe)


def mode_name(personality: Personality, mode: FlightMode, airframe: str = "quadrotor") -> str:
    """The name a ground station shows for a mode."""
    if personality is Personality.ARDUPILOT:
        to_num, _, names = _apm_tables(airframe)
        num = to_num[mode]
        return next(k for k, v in names.items() if v == num)
    main, sub = _PX4_OF_MODE[mode]
    main_name = next(k for k, v in PX4_MAIN.items() if v == main)
    if main_name != "AUTO":
        return main_name
    return "AUTO." + next(k for k, v in PX4_AUTO_SUB.items() if v == sub)


def _is_small_int(x: float) -> bool:
    try:
        return float(x).is_integer() and 0 <= x <= 255
    except (TypeError, ValueError, OverflowError):
        return False
