"""Telemetry messages built from the autopilot's state, with MAVLink's units and scalings.

This is the one place where SI/NED values become degrees, 1e7-degrees, millimetres and
centi-units. Every time field comes from the simulation clock.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from skyherd.flight.autopilot_api import Autopilot, FlightMode
from skyherd.flight.geo import ned_to_geodetic
from skyherd.flight.mavlink.modes import (
    COPTER,
    Personality,
    base_mode_of,
    custom_mode_of,
    mode_of_custom,
)
from skyherd.flight.mavlink.payload import Payload, packer

M = mavlink
SW_VERSION = (0, 1, 0)  # skyherd version, reported in AUTOPILOT_VERSION

# Sensors and controllers this simulated vehicle has (all simulated, all healthy).
SENSORS_PRESENT = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
    | M.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | M.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
    | M.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
    | M.MAV_SYS_STATUS_PREARM_CHECK
)
_SENSORS_ONLY = (
    M.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | M.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | M.MAV_SYS_STATUS_SENSOR_3D_MAG
    | M.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | M.MAV_SYS_STATUS_SENSOR_GPS
    | M.MAV_SYS_STATUS_AHRS
    | M.MAV_SYS_STATUS_SENSOR_BATTERY
    | M.MAV_SYS_STATUS_PREARM_CHECK
)

CAPABILITIES = (
    M.MAV_PROTOCOL_CAPABILITY_MISSION_INT
    | M.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
    | M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
    | M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
    | M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
    | M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE
)

# Each message's packer: its fields in `<name>_encode`'s order → its wire payload (payload.py).
_ALTITUDE = packer(M.MAVLINK_MSG_ID_ALTITUDE)
_ATTITUDE = packer(M.MAVLINK_MSG_ID_ATTITUDE)
_ATTITUDE_QUATERNION = packer(M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION)
_AUTOPILOT_VERSION = packer(M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
_BATTERY_STATUS = packer(M.MAVLINK_MSG_ID_BATTERY_STATUS)
_EXTENDED_SYS_STATE = packer(M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE)
_GLOBAL_POSITION_INT = packer(M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT)
_GPS_RAW_INT = packer(M.MAVLINK_MSG_ID_GPS_RAW_INT)
_HEARTBEAT = packer(M.MAVLINK_MSG_ID_HEARTBEAT)
_HOME_POSITION = packer(M.MAVLINK_MSG_ID_HOME_POSITION)
_LOCAL_POSITION_NED = packer(M.MAVLINK_MSG_ID_LOCAL_POSITION_NED)
_MISSION_CURRENT = packer(M.MAVLINK_MSG_ID_MISSION_CURRENT)
_SYS_STATUS = packer(M.MAVLINK_MSG_ID_SYS_STATUS)
_SYSTEM_TIME = packer(M.MAVLINK_MSG_ID_SYSTEM_TIME)
_VFR_HUD = packer(M.MAVLINK_MSG_ID_VFR_HUD)
_WIND = packer(M.MAVLINK_MSG_ID_WIND)
_WIND_COV = packer(M.MAVLINK_MSG_ID_WIND_COV)

BATTERY_CELLS = 4
CELL_EMPTY_V, CELL_FULL_V = 3.5, 4.2  # [V] linear open-circuit model against charge


@dataclass(frozen=True)
class Identity:
    """Who the vehicle says it is."""

    system_id: int
    component_id: int
    personality: Personality
    mav_type: int  # MAV_TYPE_QUADROTOR / MAV_TYPE_FIXED_WING


def prearm_ok(ap: Autopilot) -> bool:
    """Pre-arm checks as the endpoint can see them: finite state and battery above 10 %."""
    s = ap.state
    finite = all(map(math.isfinite, s.pos_ned.tolist())) and all(
        map(math.isfinite, s.quat.tolist())
    )
    return finite and ap.battery_remaining > 0.1


def battery_voltage(remaining: float) -> float:
    """Pack voltage [V] for a 4-cell LiPo at charge fraction `remaining` in [0, 1]."""
    r = min(max(remaining, 0.0), 1.0)
    return BATTERY_CELLS * (CELL_EMPTY_V + (CELL_FULL_V - CELL_EMPTY_V) * r)


_NO_REQUESTS = SimpleNamespace(mode_number=None, guided_hover=False)


class TelemetryBuilder:
    """Builds one message by id from the autopilot's current state."""

    def __init__(self, ap: Autopilot, ident: Identity):
        self.ap = ap
        self.ident = ident
        # ArduPilot: `.mode_number` last set and `.guided_hover` (the endpoint's commands)
        self.mode_requests = _NO_REQUESTS
        self._geo_t_us, self._geo_state = -1, None  # time [us] and state of the cached position
        self._geo = (0.0, 0.0, 0.0)
        self._builders = {
            M.MAVLINK_MSG_ID_HEARTBEAT: self.heartbeat,
            M.MAVLINK_MSG_ID_SYS_STATUS: self.sys_status,
            M.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: self.extended_sys_state,
            M.MAVLINK_MSG_ID_ATTITUDE: self.attitude,
            M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: self.attitude_quaternion,
            M.MAVLINK_MSG_ID_LOCAL_POSITION_NED: self.local_position_ned,
            M.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: self.global_position_int,
            M.MAVLINK_MSG_ID_GPS_RAW_INT: self.gps_raw_int,
            M.MAVLINK_MSG_ID_HOME_POSITION: self.home_position,
            M.MAVLINK_MSG_ID_BATTERY_STATUS: self.battery_status,
            M.MAVLINK_MSG_ID_ALTITUDE: self.altitude,
            M.MAVLINK_MSG_ID_VFR_HUD: self.vfr_hud,
            M.MAVLINK_MSG_ID_MISSION_CURRENT: self.mission_current,
            M.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self.autopilot_version,
            M.MAVLINK_MSG_ID_SYSTEM_TIME: self.system_time,
        }
        if getattr(ap, "wind_estimate_ned", None) is not None:  # the autopilot estimates wind
            if ident.personality is Personality.ARDUPILOT:
                self._builders[M.MAVLINK_MSG_ID_WIND] = self.wind
            else:
                self._builders[M.MAVLINK_MSG_ID_WIND_COV] = self.wind_cov

    def can_build(self, msg_id: int) -> bool:
        return msg_id in self._builders

    def build(self, msg_id: int) -> Payload:
        """Message `msg_id` now, packed (KeyError for one `can_build` says no to)."""
        return self._builders[msg_id]()

    # --- helpers -------------------------------------------------------------------------
    @property
    def _ms(self) -> int:
        return self.ap.clock.time_boot_ms & 0xFFFFFFFF

    @property
    def _us(self) -> int:
        return self.ap.clock.time_us

    def _geodetic(self) -> tuple[float, float, float]:
        """Latitude, longitude [deg], altitude AMSL [m] now (three messages of a step share it)."""
        t_us, state = self.ap.clock.time_us, self.ap.state
        if t_us != self._geo_t_us or state is not self._geo_state:
            self._geo_t_us, self._geo_state = t_us, state
            self._geo = ned_to_geodetic(self.ap.home, state.pos_ned)
        return self._geo

    # --- messages ------------------------------------------------------------------------
    def heartbeat(self) -> Payload:
        ap = self.ap
        armed = ap.armed
        status = M.MAV_STATE_ACTIVE if armed else M.MAV_STATE_STANDBY
        return _HEARTBEAT(
            self.ident.mav_type,
            self.ident.personality.mav_autopilot,
            base_mode_of(ap.mode, armed),
            self.custom_mode(ap.mode),
            status,
        )

    def custom_mode(self, mode: FlightMode) -> int:
        """HEARTBEAT `custom_mode`. With the ArduCopter personality the hover (HOLD) shows as
        real ArduCopter would: GUIDED after a take-off in GUIDED (it stays in GUIDED holding its
        target), the number asked for when a ground station set LOITER or BRAKE, else BRAKE (a
        hold of its own: the offboard-loss failsafe)."""
        ident, ap = self.ident, self.ap
        number = custom_mode_of(ident.personality, mode, ap.airframe)
        if ident.personality is not Personality.ARDUPILOT or ap.airframe == "fixedwing":
            return number
        asked = self.mode_requests.mode_number
        if mode is FlightMode.HOLD and self.mode_requests.guided_hover:
            return COPTER["GUIDED"]
        if asked is not None and mode_of_custom(ident.personality, asked, 0, ap.airframe) is mode:
            return asked
        return number

    def sys_status(self) -> Payload:
        ap = self.ap
        enabled = SENSORS_PRESENT if ap.armed else _SENSORS_ONLY
        health = (
            SENSORS_PRESENT if prearm_ok(ap) else SENSORS_PRESENT & ~M.MAV_SYS_STATUS_PREARM_CHECK
        )
        rem = ap.battery_remaining
        volts = getattr(ap, "battery_voltage", None) or battery_voltage(rem)
        return _SYS_STATUS(
            SENSORS_PRESENT,
            enabled,
            health,
            0,  # load [d%]: not measured
            int(volts * 1000),
            -1,  # current: not modelled
            int(round(rem * 100)),
            0,
            0,
            0,
            0,
            0,
            0,
        )

    def extended_sys_state(self) -> Payload:
        return _EXTENDED_SYS_STATE(M.MAV_VTOL_STATE_UNDEFINED, int(self.ap.landed_state))

    def attitude(self) -> Payload:
        s = self.ap.state
        roll, pitch, yaw = s.euler
        p, q, r = s.omega_frd.tolist()
        return _ATTITUDE(self._ms, roll, pitch, yaw, p, q, r)

    def attitude_quaternion(self) -> Payload:
        s = self.ap.state
        w, x, y, z = s.quat.tolist()
        p, q, r = s.omega_frd.tolist()
        return _ATTITUDE_QUATERNION(self._ms, w, x, y, z, p, q, r, [0.0, 0.0, 0.0, 0.0])

    def local_position_ned(self) -> Payload:
        s = self.ap.state
        x, y, z = s.pos_ned.tolist()
        vx, vy, vz = s.vel_ned.tolist()
        return _LOCAL_POSITION_NED(self._ms, x, y, z, vx, vy, vz)

    def global_position_int(self) -> Payload:
        s = self.ap.state
        lat, lon, alt = self._geodetic()
        vx, vy, vz = (_clamp_i16(v * 100) for v in s.vel_ned.tolist())
        hdg = int(round(math.degrees(s.euler[2]) * 100)) % 36000
        return _GLOBAL_POSITION_INT(
            self._ms,
            int(round(lat * 1e7)),
            int(round(lon * 1e7)),
            int(round(alt * 1000)),
            int(round(-float(s.pos_ned[2]) * 1000)),
            vx,
            vy,
            vz,
            hdg,
        )

    def gps_raw_int(self) -> Payload:
        s = self.ap.state
        lat, lon, alt = self._geodetic()
        vn, ve = s.vel_ned.tolist()[:2]
        gs = math.hypot(vn, ve)
        cog = int(round(math.degrees(math.atan2(ve, vn)) * 100)) % 36000 if gs > 0.2 else 65535
        return _GPS_RAW_INT(
            self._us,
            M.GPS_FIX_TYPE_3D_FIX,
            int(round(lat * 1e7)),
            int(round(lon * 1e7)),
            int(round(alt * 1000)),
            80,  # HDOP 0.8
            120,  # VDOP 1.2
            min(int(round(gs * 100)), 65534),
            cog,
            12,  # satellites
        )

    def home_position(self) -> Payload:
        h = self.ap.home
        return _HOME_POSITION(
            int(round(h.lat_deg * 1e7)),
            int(round(h.lon_deg * 1e7)),
            int(round(h.alt_m * 1000)),
            0.0,
            0.0,
            0.0,
            [1.0, 0.0, 0.0, 0.0],
            0.0,
            0.0,
            0.0,
            self._us,
        )

    def battery_status(self) -> Payload:
        rem = self.ap.battery_remaining
        volts = getattr(self.ap, "battery_voltage", None) or battery_voltage(rem)
        cell_mv = int(volts / BATTERY_CELLS * 1000)
        voltages = [cell_mv] * BATTERY_CELLS + [65535] * (10 - BATTERY_CELLS)
        return _BATTERY_STATUS(
            0,
            M.MAV_BATTERY_FUNCTION_ALL,
            M.MAV_BATTERY_TYPE_LIPO,
            32767,  # temperature unknown
            voltages,
            -1,
            -1,
            -1,
            int(round(rem * 100)),
        )

    def altitude(self) -> Payload:
        s = self.ap.state
        rel = -float(s.pos_ned[2])
        amsl = self.ap.home.alt_m + rel
        # Flat terrain at home's altitude: terrain height = height above home.
        return _ALTITUDE(self._us, amsl, amsl, rel, rel, rel, rel)

    def vfr_hud(self) -> Payload:
        s = self.ap.state
        vn, ve = s.vel_ned.tolist()[:2]
        gs = float(np.hypot(vn, ve))
        hdg = int(round(math.degrees(s.euler[2]))) % 360
        lat, lon, alt = self._geodetic()
        # No wind: airspeed = ground speed. Throttle: mean motor command when the autopilot
        # exposes it (multirotor), else 0.
        motors = getattr(self.ap, "motor_commands", None)
        thr = int(round(100 * (sum(motors.tolist()) / len(motors)))) if motors is not None else 0
        return _VFR_HUD(gs, gs, hdg, max(0, min(100, thr)), alt, -float(s.vel_ned[2]))

    def mission_current(self, total: int = 0) -> Payload:
        prog = self.ap.mission_progress
        state = M.MISSION_STATE_NO_MISSION if total == 0 else M.MISSION_STATE_ACTIVE
        if total and prog.finished:
            state = M.MISSION_STATE_COMPLETE
        return _MISSION_CURRENT(int(prog.current), total, state, 0)

    def autopilot_version(self) -> Payload:
        major, minor, patch = SW_VERSION
        sw = (major << 24) | (minor << 16) | (patch << 8) | 255  # FIRMWARE_VERSION_TYPE_OFFICIAL
        uid = 0x5348_0000_0000_0000 | self.ident.system_id  # "SH" + system id: unique per instance
        return _AUTOPILOT_VERSION(CAPABILITIES, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid)

    def wind_cov(self) -> Payload:
        """PX4's WIND_COV: the autopilot's own wind estimate [m/s NED, the way the air moves];
        no variance is estimated (NaN, as the message defines for unknown)."""
        w = self.ap.wind_estimate_ned.tolist()
        alt = self._geodetic()[2]
        nan = math.nan
        return _WIND_COV(self._us, w[0], w[1], w[2], nan, nan, alt, nan, nan)

    def wind(self) -> Payload:
        """ArduPilot's WIND: direction the wind comes from [deg, 0..360), speed, vertical."""
        w = self.ap.wind_estimate_ned.tolist()
        frm = math.degrees(math.atan2(-w[1], -w[0])) % 360.0
        return _WIND(frm, math.hypot(w[0], w[1]), w[2])

    def system_time(self) -> Payload:
        return _SYSTEM_TIME(0, self._ms)  # no real UTC in a simulation


def _clamp_i16(v: float) -> int:
    return int(max(-32768, min(32767, round(v))))
