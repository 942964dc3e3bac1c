"""The autopilot profiles as pure functions: modes both ways per vehicle type, streams, recipes,
parameter names, detection (numbers from px4_custom_mode.h, ArduCopter/ArduPlane mode.h)."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode
from skyherd.hil.autopilots import (
    ARDUCOPTER,
    ARDUPLANE,
    MSG,
    PX4,
    UnknownAutopilot,
    UnsupportedMode,
    detect,
)


def test_modes_are_decoded_by_vehicle_type():
    # the copter table read on a plane was the bug: 15 is GUIDED on a plane, nothing on a copter
    assert ARDUPLANE.decode_mode(15) is FlightMode.OFFBOARD and ARDUCOPTER.decode_mode(15) is None
    assert (
        ARDUPLANE.decode_mode(12) is FlightMode.HOLD and ARDUPLANE.decode_mode(1) is FlightMode.HOLD
    )
    assert ARDUPLANE.decode_mode(4) is None and ARDUPLANE.mode_name(4) == "ACRO"
    assert ARDUCOPTER.decode_mode(4) is FlightMode.OFFBOARD
    assert ARDUCOPTER.decode_mode(5) is FlightMode.POSCTL  # LOITER: the pilot's throttle
    assert ARDUCOPTER.decode_mode(2) is FlightMode.ALTCTL  # ALT_HOLD likewise
    assert ARDUCOPTER.decode_mode(17) is FlightMode.HOLD and ARDUCOPTER.mode_name(17) == "BRAKE"
    assert ARDUCOPTER.decode_mode(21) is FlightMode.RTL  # SMART_RTL
    assert PX4.decode_mode((4 << 16) | (3 << 24)) is FlightMode.HOLD
    assert PX4.mode_name((4 << 16) | (3 << 24)) == "AUTO.LOITER"
    assert PX4.decode_mode(6 << 16) is FlightMode.OFFBOARD and PX4.mode_name(6 << 16) == "OFFBOARD"
    assert PX4.decode_mode(99 << 16) is None and ARDUCOPTER.mode_name(99) == "mode 99"


def test_set_mode_params_and_unsupported_modes():
    flag = float(M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED)
    assert PX4.set_mode_params(FlightMode.HOLD) == (flag, 4.0, 3.0)
    assert PX4.set_mode_params(FlightMode.OFFBOARD) == (flag, 6.0, 0.0)
    assert ARDUCOPTER.set_mode_params(FlightMode.HOLD) == (flag, 17.0, 0.0)  # BRAKE
    assert ARDUCOPTER.set_mode_params(FlightMode.LAND) == (flag, 9.0, 0.0)
    assert ARDUPLANE.set_mode_params(FlightMode.OFFBOARD) == (flag, 15.0, 0.0)
    assert ARDUPLANE.set_mode_params(FlightMode.TAKEOFF) == (flag, 13.0, 0.0)
    with pytest.raises(UnsupportedMode, match="ArduPlane has no mode for LAND"):
        ARDUPLANE.set_mode_params(FlightMode.LAND)
    # every mode that can be set decodes back to itself (TAKEOFF is GUIDED on ArduCopter)
    for p in (PX4, ARDUCOPTER, ARDUPLANE):
        for mode in FlightMode:
            try:
                number = p.custom_mode(mode)
            except UnsupportedMode:
                continue
            back = p.decode_mode(number)
            assert back is mode or (p is ARDUCOPTER and mode is FlightMode.TAKEOFF)


def test_ai_and_fallback_modes_need_no_pilot():
    assert [p.ai_mode for p in (PX4, ARDUCOPTER, ARDUPLANE)] == [FlightMode.OFFBOARD] * 3
    names = [p.mode_name(p.custom_mode(p.fallback_mode)) for p in (PX4, ARDUCOPTER, ARDUPLANE)]
    assert names == ["AUTO.LOITER", "BRAKE", "LOITER"]
    assert "LOITER" != names[1] and "ALT_HOLD" != names[1]


def test_streams_ask_only_for_what_each_autopilot_sends():
    ap = {m for m, _ in ARDUCOPTER.stream_requests()}
    assert MSG["ATTITUDE"] in ap and MSG["EKF_STATUS_REPORT"] in ap
    assert MSG["ATTITUDE_QUATERNION"] not in ap and MSG["EXTENDED_SYS_STATE"] not in ap
    px4 = dict(PX4.stream_requests())
    assert MSG["ATTITUDE_QUATERNION"] in px4 and MSG["EXTENDED_SYS_STATE"] in px4
    for p in (PX4, ARDUCOPTER, ARDUPLANE):  # one setpoint per position sample: >= 10 Hz
        assert dict(p.stream_requests())[MSG["LOCAL_POSITION_NED"]] >= 10.0
        assert {s for s, _ in p.data_stream_requests()} >= {M.MAV_DATA_STREAM_POSITION}


def test_takeoff_recipes():
    px4 = PX4.takeoff_steps(20.0, 584.0)
    (cmd,) = [s for s in px4 if s.kind == "command"]
    assert cmd.command == M.MAV_CMD_NAV_TAKEOFF and cmd.params[6] == 604.0  # AMSL
    cop = ARDUCOPTER.takeoff_steps(20.0, 584.0)
    kinds = [s.kind for s in cop]
    assert kinds.index("set_mode") < kinds.index("arm") < kinds.index("command")
    assert kinds.index("stop_setpoints") < kinds.index("command")  # no setpoints in the climb
    (cmd,) = [s for s in cop if s.kind == "command"]
    assert cmd.params[6] == 20.0 and not any(math.isnan(x) for x in cmd.params[4:])
    assert next(s for s in cop if s.kind == "arm").retries > 1  # gyros settle: retried
    plane = ARDUPLANE.takeoff_steps(40.0, 584.0)
    assert M.MAV_CMD_NAV_TAKEOFF not in [s.command for s in plane]
    assert (
        plane[0].kind == "set_param" and plane[0].what == "TKOFF_ALT" and plane[0].params == (40.0,)
    )
    # PX4: the stream stops once the landing is accepted, before it ends (the disarm)
    land = PX4.land_steps()
    assert [s.kind for s in land] == ["set_mode", "stop_setpoints", "wait_disarmed"]
    assert land[0].mode is FlightMode.LAND  # DO_SET_MODE: PX4 stays in LAND once disarmed
    assert [s.kind for s in PX4.handover_steps()] == ["stream_setpoints", "set_mode"]
    assert ARDUPLANE.land_steps()[-1].mode is FlightMode.RTL


def test_parameter_names_per_autopilot():
    assert PX4.param_name("airspeed_trim") == "FW_AIRSPD_TRIM"
    assert ARDUPLANE.param_name("airspeed_trim") == "AIRSPEED_CRUISE"
    assert ARDUPLANE.param_name("loiter_radius") == "WP_LOITER_RAD"
    assert PX4.param_name("loiter_radius") == "NAV_LOITER_RAD"
    assert ARDUCOPTER.param_to_si("speed_max_xy", 500.0) == 5.0  # WPNAV_SPEED [cm/s]
    assert ARDUPLANE.param_to_si("bank_limit", 45.0) == pytest.approx(math.pi / 4)
    with pytest.raises(ValueError, match="no parameter for airspeed_trim"):
        ARDUCOPTER.param_name("airspeed_trim")


def test_detection():
    assert detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_QUADROTOR) is PX4
    assert detect(M.MAV_AUTOPILOT_PX4, M.MAV_TYPE_FIXED_WING).vehicle == "fixedwing"
    assert detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_HEXAROTOR) is ARDUCOPTER
    assert detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_FIXED_WING) is ARDUPLANE
    with pytest.raises(UnknownAutopilot, match="GROUND_ROVER"):
        detect(M.MAV_AUTOPILOT_ARDUPILOTMEGA, M.MAV_TYPE_GROUND_ROVER)
    with pytest.raises(UnknownAutopilot):
        detect(M.MAV_AUTOPILOT_GENERIC, M.MAV_TYPE_QUADROTOR)
    assert ARDUCOPTER.decode_mode(5) is FlightMode.POSCTL  # LOITER reads the pilot's sticks


def test_param_value_is_in_the_autopilots_unit_and_whole_where_it_stores_integers():
    """ArduPlane stores WP_LOITER_RAD and TKOFF_ALT as AP_Int16: a set value must read back as
    sent (123.613 would come back as 123 and the set would never be confirmed)."""
    from skyherd.hil.autopilots import ARDUCOPTER, ARDUPLANE, PX4

    assert ARDUPLANE.param_value("loiter_radius", 123.613) == 124.0
    assert ARDUPLANE.param_value("loiter_radius", 124.0) == 124.0
    assert ARDUPLANE.param_value("takeoff_altitude", 29.2) == 30.0
    assert PX4.param_value("loiter_radius", 123.613) == 123.613  # a float parameter
    assert abs(ARDUCOPTER.param_value("loiter_radius", 12.5) - 1250.0) < 1e-9  # [cm]
    step = ARDUPLANE.takeoff_steps(29.2, 584.0)[0]
    assert step.kind == "set_param" and step.params == (30.0,)


def test_companion_gives_arduplane_positions_as_do_reposition_and_velocities_as_a_point_ahead():
    """ArduPlane's GUIDED moves only by DO_REPOSITION (SET_POSITION_TARGET_LOCAL_NED changes
    just its altitude): the tick-driven companion sends one per second, without the change-mode
    flag (only the climb-out from TAKEOFF asks for it: a stream must not undo the net's LOITER),
    and turns a velocity command into a target 5 s ahead."""
    import numpy as np

    from skyherd.flight.geo import DEFAULT_HOME, geodetic_to_ned
    from skyherd.hil.autopilots import ARDUPLANE
    from skyherd.hil.telemetry import Home, reposition_command
    from skyherd.mission.vehicle import VehicleLink

    class Link:
        sent: list = []

        def send(self, msg) -> None:
            self.sent.append(msg)

    link = Link()
    v = VehicleLink(link, target_system=1)
    h = DEFAULT_HOME
    v.tel.profile, v.tel.home = ARDUPLANE, Home(h.lat_deg, h.lon_deg, h.alt_m)
    v.tel.pos_ned = np.array([0.0, 0.0, -50.0])
    v.t = 10.0
    v.position_target(vel_ned=[20.0, 0.0, 0.0])
    v.position_target(pos_ned=[0.0, 0.0, -60.0])  # within 1 s of the last one: not sent
    assert len(link.sent) == 1
    m = link.sent[0]
    assert m.get_type() == "COMMAND_INT" and m.command == 192  # MAV_CMD_DO_REPOSITION
    assert m.param2 == 0.0 and m.frame == 6  # no mode change (the net's hold is LOITER)
    ned = geodetic_to_ned(h, m.x / 1e7, m.y / 1e7, h.alt_m)
    assert abs(ned[0] - 100.0) < 0.5 and abs(ned[1]) < 0.5 and abs(m.z - 50.0) < 1e-6
    v.t = 11.0
    v.position_target(pos_ned=[0.0, 30.0, -60.0])
    assert len(link.sent) == 2 and abs(link.sent[1].z - 60.0) < 1e-6
    climb = reposition_command(v.tel, ARDUPLANE, 1, [0.0, 0.0, -60.0], change_mode=True)
    assert climb.param2 == 1.0  # MAV_DO_REPOSITION_FLAGS_CHANGE_MODE
