"""The multirotor autopilot's parameters (PX4 names where PX4 has the same meaning).

Units follow PX4 for PX4 names (a few are in degrees); the autopilot converts once.
Rate-loop gains are in this autopilot's own units (angular acceleration per rate error),
not PX4's normalised ones: keep that in mind when copying values from a PX4 vehicle.
"""

from __future__ import annotations

from skyherd.flight.geofence import GEOFENCE_PARAMS
from skyherd.flight.params import ParamSpec
from skyherd.runio.constants import POS_SPEED_MAX_MPS

MULTIROTOR_PARAMS: tuple[ParamSpec, ...] = (
    # --- position / velocity loops
    ParamSpec("MPC_XY_P", 0.95, 0.0, 5.0, "horizontal position gain", "1/s"),
    ParamSpec("MPC_Z_P", 1.0, 0.0, 5.0, "vertical position gain", "1/s"),
    ParamSpec("MPC_XY_VEL_P_ACC", 3.5, 0.0, 10.0, "horizontal velocity gain", "1/s"),
    ParamSpec("MPC_XY_VEL_I_ACC", 1.0, 0.0, 10.0, "horizontal velocity integral", "1/s^2"),
    ParamSpec("MPC_Z_VEL_P_ACC", 4.0, 0.0, 15.0, "vertical velocity gain", "1/s"),
    ParamSpec("MPC_Z_VEL_I_ACC", 2.0, 0.0, 10.0, "vertical velocity integral", "1/s^2"),
    ParamSpec("MPC_VEL_I_LIM", 3.0, 0.0, 10.0, "velocity integrator limit", "m/s^2"),
    ParamSpec("MPC_DRAG_FF", 1.0, 0.0, 2.0, "drag feed-forward (× airframe drag)", "-"),
    ParamSpec("MPC_VEL_I_ERR", 1.0, 0.01, 20.0, "integrate only velocity errors below", "m/s"),
    ParamSpec(
        "MPC_XY_VEL_MAX", POS_SPEED_MAX_MPS, 0.0, 20.0, "horizontal speed limit (offboard)", "m/s"
    ),
    ParamSpec("MPC_XY_CRUISE", 5.0, 0.0, 20.0, "horizontal speed in auto modes", "m/s"),
    ParamSpec("MPC_VEL_MANUAL", 10.0, 0.0, 20.0, "horizontal speed at full stick", "m/s"),
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "climb rate limit", "m/s"),
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "descent rate limit", "m/s"),
    ParamSpec("MPC_TKO_SPEED", 3.0, 0.5, 5.0, "takeoff climb rate", "m/s"),
    ParamSpec("MPC_LAND_SPEED", 0.7, 0.2, 2.0, "descent rate near the ground", "m/s"),
    ParamSpec("MPC_LAND_ALT1", 10.0, 0.0, 100.0, "below this height land slowly", "m"),
    ParamSpec("MPC_TILTMAX_AIR", 45.0, 20.0, 89.0, "tilt limit in flight", "deg"),
    ParamSpec("MPC_MAN_TILT_MAX", 35.0, 0.0, 89.0, "tilt at full stick", "deg"),
    ParamSpec("MPC_MAN_Y_MAX", 150.0, 0.0, 400.0, "yaw rate at full stick", "deg/s"),
    ParamSpec("MPC_THR_MIN", 0.12, 0.05, 0.5, "least collective in flight", "fraction of max"),
    ParamSpec("MPC_THR_MAX", 0.95, 0.5, 1.0, "largest collective", "fraction of max"),
    ParamSpec("MOT_SPIN_ARM", 0.1, 0.0, 0.3, "motor command while armed on ground", "-"),
    # --- trajectory shaping (off by default; on in the PX4 stand-in set, docs/quadrotor.md)
    ParamSpec(
        "SH_POS_SMOOTH", 0.0, 0.0, 2.0, "shape targets: 0 off, 1 auto modes, 2 + offboard", "-"
    ),
    ParamSpec("MPC_ACC_HOR", 3.0, 0.5, 15.0, "horizontal acceleration of shaped targets", "m/s^2"),
    ParamSpec("MPC_XY_TRAJ_P", 0.5, 0.1, 1.0, "shaped approach: speed per metre to go", "1/s"),
    ParamSpec("MPC_ACC_UP_MAX", 4.0, 1.0, 15.0, "upward acceleration of shaped targets", "m/s^2"),
    ParamSpec(
        "MPC_ACC_DOWN_MAX", 3.0, 1.0, 15.0, "downward acceleration of shaped targets", "m/s^2"
    ),
    ParamSpec("MPC_JERK_AUTO", 4.0, 1.0, 80.0, "jerk limit of shaped targets", "m/s^3"),
    # --- attitude / rate loops
    ParamSpec("MC_ROLL_P", 6.5, 0.0, 20.0, "roll attitude gain", "1/s"),
    ParamSpec("MC_PITCH_P", 6.5, 0.0, 20.0, "pitch attitude gain", "1/s"),
    ParamSpec("MC_YAW_P", 2.8, 0.0, 10.0, "yaw attitude gain", "1/s"),
    ParamSpec("MC_ROLLRATE_MAX", 220.0, 0.0, 1800.0, "roll rate limit", "deg/s"),
    ParamSpec("MC_PITCHRATE_MAX", 220.0, 0.0, 1800.0, "pitch rate limit", "deg/s"),
    ParamSpec("MC_YAWRATE_MAX", 200.0, 0.0, 1800.0, "yaw rate limit", "deg/s"),
    ParamSpec("MC_ROLLRATE_P", 20.0, 0.0, 100.0, "roll rate gain (ang. acc. per rate)", "1/s"),
    ParamSpec("MC_PITCHRATE_P", 20.0, 0.0, 100.0, "pitch rate gain", "1/s"),
    ParamSpec("MC_YAWRATE_P", 8.0, 0.0, 100.0, "yaw rate gain", "1/s"),
    ParamSpec("MC_ROLLRATE_I", 10.0, 0.0, 200.0, "roll rate integral", "1/s^2"),
    ParamSpec("MC_PITCHRATE_I", 10.0, 0.0, 200.0, "pitch rate integral", "1/s^2"),
    ParamSpec("MC_YAWRATE_I", 4.0, 0.0, 200.0, "yaw rate integral", "1/s^2"),
    ParamSpec("MC_ROLLRATE_D", 0.2, 0.0, 5.0, "roll rate derivative", "-"),
    ParamSpec("MC_PITCHRATE_D", 0.2, 0.0, 5.0, "pitch rate derivative", "-"),
    ParamSpec("MC_YAWRATE_D", 0.0, 0.0, 5.0, "yaw rate derivative", "-"),
    ParamSpec("MC_RATE_I_LIM", 20.0, 0.0, 200.0, "rate integrator limit", "rad/s^2"),
    # --- navigation
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, 0.5, 100.0, "default takeoff height", "m"),
    ParamSpec("RTL_RETURN_ALT", 30.0, 0.0, 500.0, "least height for the return leg", "m"),
    ParamSpec("NAV_ACC_RAD", 2.0, 0.05, 200.0, "waypoint acceptance radius", "m"),
    ParamSpec("NAV_MC_ALT_RAD", 0.8, 0.05, 10.0, "waypoint altitude acceptance", "m"),
    # --- commander
    ParamSpec("COM_OF_LOSS_T", 0.5, 0.0, 60.0, "offboard setpoint timeout → hold", "s"),
    ParamSpec("COM_RC_LOSS_T", 0.5, 0.0, 35.0, "manual control timeout → hold", "s"),
    ParamSpec("COM_DISARM_LAND", 2.0, -1.0, 20.0, "disarm after landing (<0 never)", "s"),
    ParamSpec("COM_DISARM_PRFLT", 10.0, -1.0, 60.0, "disarm if no takeoff (<0 never)", "s"),
    ParamSpec("LNDMC_TRIG_TIME", 0.5, 0.1, 10.0, "ground contact time to detect a landing", "s"),
    ParamSpec("BAT_LOW_THR", 0.15, 0.0, 0.5, "battery fraction reported as low", "-"),
    ParamSpec("BAT_CRIT_THR", 0.07, 0.0, 0.5, "battery fraction → return (RTL)", "-"),
    ParamSpec("BAT_EMERGEN_THR", 0.05, 0.0, 0.5, "battery fraction → land here", "-"),
    ParamSpec("EKF2_NOAID_TOUT", 5.0, 0.5, 60.0, "dead reckoning without GPS, then land", "s"),
    *GEOFENCE_PARAMS,
)
