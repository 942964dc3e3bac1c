"""The fixed-wing autopilot's parameters: PX4 names, defaults, ranges, units.

Values keep PX4's unit for each name (degrees where PX4 uses degrees); the autopilot converts
to SI where it reads them. Defaults fit the J3Cub from the jsbsim wheel (1-g stall 17.5 m/s at
full weight: sqrt(2 W / (rho S CL_max)) with W = 5.43 kN, S = 16.6 m^2, CL_max = 1.85).
"""

from __future__ import annotations

from skyherd.flight.geofence import GEOFENCE_PARAMS
from skyherd.flight.params import ParamSpec

# PX4 names and units (degrees where PX4 uses degrees). One source of truth for each value.
FW_PARAM_SPECS: tuple[ParamSpec, ...] = (
    ParamSpec("FW_AIRSPD_TRIM", 24.0, 18.0, 40.0, "cruise airspeed", "m/s"),
    ParamSpec("FW_AIRSPD_MIN", 20.0, 15.0, 30.0, "minimum commanded airspeed", "m/s"),
    ParamSpec("FW_AIRSPD_MAX", 38.0, 25.0, 50.0, "maximum airspeed", "m/s"),
    ParamSpec("FW_AIRSPD_STALL", 17.5, 10.0, 25.0, "1 g stall speed (J3Cub, full weight)", "m/s"),
    ParamSpec("FW_R_LIM", 35.0, 10.0, 50.0, "bank angle limit", "deg"),
    ParamSpec("FW_P_LIM_MAX", 15.0, 5.0, 30.0, "maximum pitch", "deg"),
    ParamSpec("FW_P_LIM_MIN", -12.0, -30.0, -3.0, "minimum pitch", "deg"),
    ParamSpec("FW_T_CLMB_MAX", 2.5, 0.5, 6.0, "maximum climb rate", "m/s"),
    ParamSpec("FW_T_SINK_MAX", 3.0, 1.0, 8.0, "maximum sink rate", "m/s"),
    ParamSpec("FW_THR_MIN", 0.0, 0.0, 1.0, "throttle floor in flight", ""),
    ParamSpec("FW_THR_MAX", 1.0, 0.0, 1.0, "throttle ceiling", ""),
    ParamSpec("NAV_L1_PERIOD", 17.0, 5.0, 50.0, "L1 period", "s"),
    ParamSpec("NAV_L1_DAMPING", 0.75, 0.6, 0.9, "L1 damping", ""),
    ParamSpec("NAV_LOITER_RAD", 0.0, 0.0, 1000.0, "loiter radius, 0 = from turn performance", "m"),
    ParamSpec("NAV_ACC_RAD", 30.0, 5.0, 200.0, "waypoint acceptance radius", "m"),
    ParamSpec("MIS_TAKEOFF_ALT", 40.0, 10.0, 300.0, "take-off altitude above home", "m"),
    ParamSpec("RTL_RETURN_ALT", 60.0, 20.0, 300.0, "return altitude above home", "m"),
    ParamSpec("RTL_LAND_DELAY", -1.0, -1.0, 600.0, "loiter before landing, -1 = loiter", "s"),
    ParamSpec("FW_TKO_AIRSPD", 18.5, 12.0, 30.0, "take-off rotation airspeed", "m/s"),
    ParamSpec("FW_LND_AIRSPD", 19.5, 15.0, 30.0, "approach airspeed", "m/s"),
    ParamSpec("FW_LND_ANG", 4.0, 2.0, 12.0, "glide slope", "deg"),
    ParamSpec("FW_LND_APP_ALT", 25.0, 10.0, 100.0, "height at the approach gate", "m"),
    ParamSpec("FW_LND_FLALT", 3.0, 0.5, 10.0, "flare height (wheels)", "m"),
    ParamSpec("COM_OF_LOSS_T", 0.5, 0.1, 10.0, "offboard setpoint timeout", "s"),
    ParamSpec("BAT_CRIT_THR", 0.07, 0.0, 0.5, "battery (fuel) fraction → return (RTL)", "-"),
    ParamSpec("BAT_EMERGEN_THR", 0.05, 0.0, 0.5, "battery (fuel) fraction → land", "-"),
    ParamSpec("COM_DISARM_LAND", 2.0, -1.0, 20.0, "disarm after landing, -1 = never", "s"),
    ParamSpec("EKF2_NOAID_TOUT", 5.0, 0.5, 60.0, "dead reckoning without GPS, then loiter", "s"),
    *GEOFENCE_PARAMS,
)
