"""pymavlink drives the vehicle's endpoint over real UDP sockets: telemetry and its rates,
commands, parameters (with persistence), missions flown in AUTO, fences, rally, several
instances, the ArduPilot personality. The vehicle is the real MultirotorAutopilot."""

from __future__ import annotations

import json
import logging
import math
import time

import numpy as np
import pytest
from mavlink_support import Client, item_fields, running_sitl, same_items, v2_connection
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode, MissionCommand
from skyherd.flight.geo import DEFAULT_HOME, geodetic_to_ned, ned_to_geodetic
from skyherd.flight.mavlink import EndpointConfig, Personality
from skyherd.flight.mavlink.modes import custom_mode_of

HOME = DEFAULT_HOME
PX4_HOLD = (4 << 16) | (3 << 24)


def _ll(north: float, east: float) -> tuple[int, int]:
    lat, lon, _ = ned_to_geodetic(HOME, np.array([north, east, 0.0]))
    return int(round(lat * 1e7)), int(round(lon * 1e7))


def test_telemetry_streams_rates_and_requests():
    with running_sitl(instance=3, speedup=5.0) as sitl, Client(3) as c:
        hb = c.wait_heartbeat()
        assert (hb.get_srcSystem(), hb.get_srcComponent()) == (4, 1)
        assert hb.type == M.MAV_TYPE_QUADROTOR and hb.autopilot == M.MAV_AUTOPILOT_PX4
        assert hb.custom_mode == PX4_HOLD and hb.base_mode & M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        assert not hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
        # Collect 2 s of wall time = about 10 s of simulation time.
        seen: dict[str, list[int]] = {}
        wall0 = time.monotonic()
        first_ms = None
        while time.monotonic() - wall0 < 2.0:
            m = c.conn.recv_match(blocking=True, timeout=0.5)
            if m is None:
                continue
            t_ms = getattr(m, "time_boot_ms", None)
            if t_ms is None and hasattr(m, "time_usec"):
                t_ms = m.time_usec // 1000
            seen.setdefault(m.get_type(), []).append(t_ms)
            if first_ms is None and t_ms is not None:
                first_ms = t_ms
        wall = time.monotonic() - wall0
        for name in ("HEARTBEAT", "SYS_STATUS", "ATTITUDE", "ATTITUDE_QUATERNION", "LOCAL_POSITION_NED",
                     "GLOBAL_POSITION_INT", "GPS_RAW_INT", "HOME_POSITION", "EXTENDED_SYS_STATE",
                     "BATTERY_STATUS", "ALTITUDE", "VFR_HUD", "MISSION_CURRENT"):  # fmt: skip
            assert name in seen, f"{name} not streamed"
        # Rates measured against the simulation clock the messages carry.
        for name, hz in (("ATTITUDE", 20), ("LOCAL_POSITION_NED", 10), ("GLOBAL_POSITION_INT", 10)):
            ts = seen[name]
            rate = (len(ts) - 1) / ((ts[-1] - ts[0]) / 1000.0)
            assert rate == pytest.approx(hz, rel=0.05), name
        # Time fields come from the simulation clock: it runs ~5x faster than the wall.
        att = seen["ATTITUDE"]
        assert (att[-1] - att[0]) / 1000.0 / wall == pytest.approx(5.0, rel=0.25)
        assert att == sorted(att)

        st = c.recv("SYS_STATUS")
        for bit in (
            M.MAV_SYS_STATUS_SENSOR_GPS,
            M.MAV_SYS_STATUS_SENSOR_3D_GYRO,
            M.MAV_SYS_STATUS_PREARM_CHECK,
        ):
            assert (
                st.onboard_control_sensors_present & bit and st.onboard_control_sensors_health & bit
            )
        gp = c.recv("GLOBAL_POSITION_INT")
        assert gp.lat == round(HOME.lat_deg * 1e7) and gp.lon == round(HOME.lon_deg * 1e7)
        assert abs(gp.alt - HOME.alt_m * 1000) < 50 and abs(gp.relative_alt) < 50
        hp = c.recv("HOME_POSITION")
        assert (hp.latitude, hp.longitude, hp.altitude) == (
            round(HOME.lat_deg * 1e7), round(HOME.lon_deg * 1e7), round(HOME.alt_m * 1000))  # fmt: skip
        assert c.recv("EXTENDED_SYS_STATE").landed_state == M.MAV_LANDED_STATE_ON_GROUND

        # SET_MESSAGE_INTERVAL: ATTITUDE at 50 Hz, then off, then back to the default.
        ack = c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 20000)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        c.drain()
        ts = []
        while len(ts) < 60:
            ts.append(c.recv("ATTITUDE").time_boot_ms)
        assert (len(ts) - 1) / ((ts[-1] - ts[0]) / 1000.0) == pytest.approx(50.0, rel=0.05)
        ack = c.command(M.MAV_CMD_GET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert c.recv("MESSAGE_INTERVAL").interval_us == 20000
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, -1).result == 0
        c.drain()
        assert c.recv("ATTITUDE", timeout=0.6) is None
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 0).result == 0
        assert c.recv("ATTITUDE", timeout=1.0) is not None
        # A message we cannot produce is refused, and the other link kept its own rates.
        assert c.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, 9999, 1000).result == M.MAV_RESULT_DENIED
        assert sitl.endpoint.streams["gcs"].rates[M.MAVLINK_MSG_ID_ATTITUDE] == 15.0  # PX4 normal

        # REQUEST_MESSAGE: ACK first, then the message. QGC's optional steps are UNSUPPORTED.
        c.mav.command_long_send(
            4, 1, M.MAV_CMD_REQUEST_MESSAGE, 0, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0
        )
        first = c.recv(["COMMAND_ACK", "AUTOPILOT_VERSION"])
        assert first.get_type() == "COMMAND_ACK" and first.result == M.MAV_RESULT_ACCEPTED
        av = c.recv("AUTOPILOT_VERSION")
        for cap in (M.MAV_PROTOCOL_CAPABILITY_MISSION_INT, M.MAV_PROTOCOL_CAPABILITY_COMMAND_INT,
                    M.MAV_PROTOCOL_CAPABILITY_MAVLINK2, M.MAV_PROTOCOL_CAPABILITY_MISSION_FENCE,
                    M.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED):  # fmt: skip
            assert av.capabilities & cap
        assert not av.capabilities & M.MAV_PROTOCOL_CAPABILITY_MISSION_RALLY
        assert (
            c.command(M.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1).result == M.MAV_RESULT_ACCEPTED
        )
        assert c.recv("AUTOPILOT_VERSION") is not None
        for msg_id in (395, 397, 435):  # component information / metadata, available modes
            assert c.command(M.MAV_CMD_REQUEST_MESSAGE, msg_id).result == M.MAV_RESULT_UNSUPPORTED
        assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_HOME_POSITION).result == 0
        assert c.command(M.MAV_CMD_DO_SET_SERVO, 1, 1500).result == M.MAV_RESULT_UNSUPPORTED


def test_commands_flight_denials_and_retries():
    with running_sitl(instance=4, speedup=10.0) as sitl, Client(4) as c:
        ap = sitl.autopilot
        c.wait_heartbeat()
        # Refusals: bad parameters and autopilot refusals are DENIED with a STATUSTEXT reason.
        c.drain()
        ack = c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 2.0)
        assert ack.result == M.MAV_RESULT_DENIED
        assert c.saw_text("param1")
        ack = c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, HOME.alt_m + 5)
        assert ack.result == M.MAV_RESULT_DENIED and not ap.armed  # not armed yet
        assert c.saw_text("arm first")
        ack = c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0)  # OFFBOARD without setpoints
        assert ack.result == M.MAV_RESULT_DENIED and ap.mode == FlightMode.HOLD
        assert (
            c.command(M.MAV_CMD_DO_SET_MODE, 1, 9, 9).result == M.MAV_RESULT_DENIED
        )  # no such mode

        # Arm, take off to 5 m (param7 is AMSL for PX4), HOLD afterwards.
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        assert c.recv("HEARTBEAT", cond=lambda m: m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
        ack = c.command(
            M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, HOME.alt_m + 5
        )
        assert ack.result == M.MAV_RESULT_ACCEPTED
        hb = c.recv("HEARTBEAT", 5, lambda m: m.custom_mode == (4 << 16 | 2 << 24))  # AUTO.TAKEOFF
        assert hb is not None
        lp = c.recv("LOCAL_POSITION_NED", 8, lambda m: m.z < -4.6 and abs(m.vz) < 0.3)
        assert lp is not None
        assert c.recv("HEARTBEAT", 5, lambda m: m.custom_mode == PX4_HOLD) is not None
        assert c.recv(
            "EXTENDED_SYS_STATE", 3, lambda m: m.landed_state == M.MAV_LANDED_STATE_IN_AIR
        )

        # Disarming in the air is refused with the autopilot's reason; nothing changes.
        c.drain()
        ack = c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0)
        assert ack.result == M.MAV_RESULT_DENIED and ap.armed
        assert c.saw_text("in the air")

        # DO_REPOSITION as COMMAND_INT (relative altitude): 8 m north, 6 m up.
        lat, lon = _ll(8.0, 0.0)
        ack = c.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                            -1, 1, 0, math.nan, lat, lon, 6.0)  # fmt: skip
        assert ack.result == M.MAV_RESULT_ACCEPTED
        lp = c.recv("LOCAL_POSITION_NED", 15,
                    lambda m: abs(m.x - 8) < 0.3 and abs(m.z + 6) < 0.3 and math.hypot(m.vx, m.vz) < 0.2)  # fmt: skip
        assert lp is not None
        # Out-of-range reposition: refused, the target does not move.
        ack = c.command_int(M.MAV_CMD_DO_REPOSITION, M.MAV_FRAME_GLOBAL_INT, -1, 1, 0, 0,
                            int(91e7), lon, 600.0)  # fmt: skip
        assert ack.result == M.MAV_RESULT_DENIED

        # A retry (confirmation 1, same params) is answered but not executed again.
        calls = []
        real_land = ap.land
        ap.land = lambda: (calls.append(ap.clock.t), real_land())[1]
        try:
            assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan).result == M.MAV_RESULT_ACCEPTED
            assert c.command(M.MAV_CMD_NAV_LAND, 0, 0, 0, math.nan, confirmation=1).result == 0
            assert len(calls) == 1
        finally:
            del ap.land
        assert c.recv("HEARTBEAT", 3, lambda m: m.custom_mode == (4 << 16 | 6 << 24)) is not None
        # Lands and auto-disarms (COM_DISARM_LAND).
        hb = c.recv("HEARTBEAT", 20, lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
        assert hb is not None and ap.state.on_ground
        assert abs(ap.state.pos_ned[0] - 8.0) < 0.5

        # Force arm (21196) and force disarm work on the ground.
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, 21196).result == 0 and ap.armed
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196).result == 0 and not ap.armed


def test_params_list_read_set_and_persistence(tmp_path, caplog):
    with running_sitl(instance=5, speedup=5.0, state_dir=tmp_path) as sitl, Client(5) as c:
        c.wait_heartbeat()
        names = sitl.autopilot.param_names()
        got = c.param_list()
        assert sorted(got) == sorted(names)
        assert sorted(v[1] for v in got.values()) == list(range(len(names)))
        assert all(v[2] == len(names) for v in got.values())
        for n in names:
            assert got[n][0] == pytest.approx(sitl.autopilot.get_param(n), rel=1e-6)
        # Read by name and by index.
        assert c.param_read("MPC_XY_CRUISE").param_value == pytest.approx(5.0)
        c.mav.param_request_read_send(6, 1, b"", 3)
        assert c.recv("PARAM_VALUE", cond=lambda m: m.param_index == 3).param_id == names[3]
        # Set: echoed, applied, saved atomically.
        assert c.param_set("MPC_XY_CRUISE", 7.5).param_value == pytest.approx(7.5)
        assert sitl.autopilot.get_param("MPC_XY_CRUISE") == 7.5
        saved = json.loads((tmp_path / "quadrotor-5" / "params.json").read_text())
        assert saved["params"] == {"MPC_XY_CRUISE": 7.5}
        # Refused sets answer the unchanged value: out of range, NaN.
        assert c.param_set("MPC_XY_CRUISE", 500.0).param_value == pytest.approx(7.5)
        assert c.param_set("MPC_XY_CRUISE", math.nan).param_value == pytest.approx(7.5)
        assert c.param_set("NO_SUCH_PARAM", 1.0, timeout=0.5) is None
        assert sitl.autopilot.get_param("MPC_XY_CRUISE") == 7.5

    # Restart: the value persisted.
    with running_sitl(instance=5, speedup=5.0, state_dir=tmp_path) as sitl, Client(5) as c:
        c.wait_heartbeat()
        assert c.param_read("MPC_XY_CRUISE").param_value == pytest.approx(7.5)

    # A corrupt file: a warning, defaults, and the vehicle runs.
    (tmp_path / "quadrotor-5" / "params.json").write_text('{"version": 1, "params": {"MPC_XY')
    with (
        caplog.at_level(logging.WARNING),
        running_sitl(instance=5, speedup=5.0, state_dir=tmp_path) as sitl,
        Client(5) as c,
    ):
        c.wait_heartbeat()
        assert c.param_read("MPC_XY_CRUISE").param_value == pytest.approx(5.0)
    assert any("unreadable" in r.message for r in caplog.records)


def test_mission_fence_rally_and_auto_flight():
    with running_sitl(instance=6, speedup=10.0) as sitl, Client(6) as c:
        ap = sitl.autopilot
        c.wait_heartbeat()
        rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        wp1, wp2 = _ll(15.0, 0.0), _ll(15.0, 10.0)
        mission = [
            (rel, MissionCommand.TAKEOFF, 0, 0, 0, math.nan, 0, 0, 6.0),
            (rel, MissionCommand.WAYPOINT, 0, 1.0, 0, math.nan, *wp1, 6.0),
            (rel, MissionCommand.WAYPOINT, 0, 1.0, 0, 90.0, *wp2, 8.0),
            (rel, MissionCommand.LAND, 0, 0, 0, math.nan, *wp2, 0.0),
        ]
        ack = c.mission_upload(mission)
        assert ack.type == M.MAV_MISSION_ACCEPTED
        down = c.mission_download()
        assert same_items([item_fields(m) for m in down], mission)
        # What the autopilot got: NED positions about home.
        items = ap._items
        assert [it.command for it in items] == [22, 16, 16, 21]
        assert items[1].pos_ned == pytest.approx(
            geodetic_to_ned(HOME, wp1[0] / 1e7, wp1[1] / 1e7, HOME.alt_m + 6), abs=0.02
        )
        assert items[2].yaw == pytest.approx(math.pi / 2) and items[1].accept_radius == 1.0

        # Fence: an inclusion polygon (4 vertices) and an exclusion circle; kept for the net.
        corners = [_ll(-50, -50), _ll(-50, 50), _ll(50, 50), _ll(50, -50)]
        fence = [(M.MAV_FRAME_GLOBAL, 5001, 4, 0, 0, 0, *ll, 0.0) for ll in corners]
        fence.append((M.MAV_FRAME_GLOBAL, 5004, 10.0, 0, 0, 0, *_ll(30, 30), 0.0))
        assert c.mission_upload(fence, mission_type=1).type == M.MAV_MISSION_ACCEPTED
        assert same_items([item_fields(m) for m in c.mission_download(1)], fence)
        shapes = sitl.endpoint.missions.fence_shapes
        assert [s.kind for s in shapes] == ["polygon", "circle"]
        assert shapes[0].inclusion and not shapes[1].inclusion and shapes[1].radius == 10.0
        assert shapes[0].vertices_ne == pytest.approx(
            np.array([[-50, -50], [-50, 50], [50, 50], [50, -50]]), abs=0.02
        )
        # A bad fence (3-vertex count on 2 items) is refused; the old one is kept.
        bad = [(M.MAV_FRAME_GLOBAL, 5001, 3, 0, 0, 0, *ll, 0.0) for ll in corners[:2]]
        assert c.mission_upload(bad, mission_type=1).type != M.MAV_MISSION_ACCEPTED
        assert len(sitl.endpoint.missions.lists[1]) == 5
        # Mission messages addressed to MAV_COMP_ID_MISSIONPLANNER (190) are answered, as by PX4.
        c.mav.mission_request_list_send(7, M.MAV_COMP_ID_MISSIONPLANNER, 1)
        assert c.recv("MISSION_COUNT", cond=lambda m: m.mission_type == 1).count == 5
        # Rally: none, and none accepted.
        assert c.mission_download(2) == []
        assert c.mission_upload([fence[0]], mission_type=2).type == M.MAV_MISSION_UNSUPPORTED
        # An unsupported mission command is refused; the uploaded mission stays.
        bad_mission = [mission[0], (rel, 178, 1, 5, -1, 0, 0, 0, 0.0)]
        assert c.mission_upload(bad_mission).type == M.MAV_MISSION_UNSUPPORTED
        assert len(c.mission_download()) == 4

        # Fly it in AUTO: MISSION_ITEM_REACHED for every item, MISSION_CURRENT advancing.
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert c.command(M.MAV_CMD_MISSION_START, 0, 3).result == M.MAV_RESULT_ACCEPTED
        reached, currents = [], set()
        deadline = time.monotonic() + 15
        while time.monotonic() < deadline and len(reached) < 4:
            m = c.recv(["MISSION_ITEM_REACHED", "MISSION_CURRENT"], 1.0)
            if m is None:
                continue
            if m.get_type() == "MISSION_ITEM_REACHED":
                reached.append(m.seq)
            else:
                currents.add(m.seq)
                assert m.total == 4
        assert reached == [0, 1, 2, 3] and currents >= {0, 1, 2, 3}
        assert c.recv("HEARTBEAT", 10, lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED)
        assert ap.state.pos_ned[:2] == pytest.approx([15.0, 10.0], abs=1.0)

        # Clearing the mission leaves the fence.
        assert c.mission_clear(0).type == M.MAV_MISSION_ACCEPTED
        assert c.mission_download(0) == [] and len(c.mission_download(1)) == 5
        assert (
            c.mission_clear(1).type == M.MAV_MISSION_ACCEPTED
            and sitl.endpoint.missions.fence_shapes == []
        )


def test_two_instances_side_by_side_and_reply_to_sender():
    with running_sitl(instance=7, speedup=5.0) as s7, running_sitl(instance=8, speedup=5.0) as s8:
        with Client(7) as c7, Client(8) as c8:
            assert c7.wait_heartbeat().get_srcSystem() == 8
            assert c8.wait_heartbeat().get_srcSystem() == 9
            assert c7.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
            assert s7.autopilot.armed and not s8.autopilot.armed
            # Wrong target: instance 8's vehicle ignores a command for system 8.
            c8.mav.command_long_send(8, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            assert c8.recv("COMMAND_ACK", 0.5) is None and not s8.autopilot.armed
        # A second vehicle on the same instance cannot bind: a clear error, no clash.
        with pytest.raises(OSError, match="cannot bind"):
            from skyherd.flight.mavlink import MavlinkEndpoint

            MavlinkEndpoint(s7.autopilot, EndpointConfig(instance=7))
        # The ground-station socket answers whoever talks to it (here udpout from any port).
        g = v2_connection("udpout:127.0.0.1:18578", source_system=254)
        try:
            g.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            deadline = time.monotonic() + 3
            hb = None
            while hb is None and time.monotonic() < deadline:
                m = g.recv_match(blocking=True, timeout=0.5)
                if m is not None and m.get_type() == "HEARTBEAT" and m.get_srcSystem() == 9:
                    hb = m
            assert hb is not None
        finally:
            g.close()


def test_ardupilot_personality():
    with (
        running_sitl(instance=9, speedup=10.0, personality=Personality.ARDUPILOT) as sitl,
        Client(9) as c,
    ):
        hb = c.wait_heartbeat()
        # its hold on the ground shows as BRAKE (17): LOITER reads a pilot's throttle
        assert hb.autopilot == M.MAV_AUTOPILOT_ARDUPILOTMEGA and hb.custom_mode == 17
        assert custom_mode_of(Personality.ARDUPILOT, FlightMode.RTL) == 6
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        # ArduCopter: NAV_TAKEOFF param7 is the height above home.
        assert c.command(M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 4.0).result == 0
        assert c.recv("LOCAL_POSITION_NED", 8, lambda m: m.z < -3.7 and abs(m.vz) < 0.3) is not None
        # Legacy SET_MODE message with an ArduCopter number (LAND = 9), acked like ArduPilot.
        c.mav.set_mode_send(10, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 9)
        ack = c.recv("COMMAND_ACK", cond=lambda m: m.command == M.MAVLINK_MSG_ID_SET_MODE)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        assert c.recv("HEARTBEAT", 3, lambda m: m.custom_mode == 9) is not None
        assert sitl.autopilot.mode == FlightMode.LAND
        # DO_SET_MODE with param2 = mode number: LOITER (5) → HOLD.
        assert (
            c.command(M.MAV_CMD_DO_SET_MODE, 1, 5).result == 0
            and sitl.autopilot.mode == FlightMode.HOLD
        )
        # ... and then shows the number asked for, as ArduCopter would
        assert c.recv("HEARTBEAT", 3, lambda m: m.custom_mode == 5) is not None


def test_qgroundcontrol_connection_sequence_on_the_gcs_link():
    """QGC's order (PROTOCOLS.md): heartbeat, AUTOPILOT_VERSION, component information,
    available modes, all parameters, mission, geofence, rally — each step answered."""
    with running_sitl(instance=18, speedup=5.0) as sitl, Client(18, port=18588, mode="udpout") as c:
        c.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, M.MAV_STATE_ACTIVE)
        hb = c.wait_heartbeat()
        assert hb.get_srcSystem() == 19
        assert c.command(M.MAV_CMD_REQUEST_PROTOCOL_VERSION, 1).result == M.MAV_RESULT_UNSUPPORTED
        assert c.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION).result == 0
        assert c.recv("AUTOPILOT_VERSION").capabilities & M.MAV_PROTOCOL_CAPABILITY_MAVLINK2
        for msg_id in (395, 397, 435):
            assert (
                c.command(M.MAV_CMD_REQUEST_MESSAGE, msg_id, 1).result == M.MAV_RESULT_UNSUPPORTED
            )
        assert len(c.param_list()) == len(sitl.autopilot.param_names())
        assert (
            c.mission_download(0) == []
            and c.mission_download(1) == []
            and c.mission_download(2) == []
        )
        assert (
            sitl.endpoint.rx_types["HEARTBEAT"] >= 1
            and sitl.endpoint.stats["rx_handler_error"] == 0
        )


def test_in_progress_then_final_ack_when_the_autopilot_reports_a_running_command():
    """An autopilot that reports takeoff as still running (Result.in_progress) gets
    IN_PROGRESS first and ACCEPTED once it hovers at the target (the real multirotor
    autopilot, with only its takeoff answer marked in_progress)."""
    from skyherd.flight.autopilot_api import Result
    from skyherd.flight.clock import SimClock
    from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
    from skyherd.flight.sitl import Sitl

    class SlowAck(MultirotorAutopilot):
        def takeoff(self, altitude=None):
            r = super().takeoff(altitude)
            return Result(r.ok, r.reason, in_progress=r.ok)

    with (
        Sitl(SlowAck(clock=SimClock()), EndpointConfig(instance=19), speedup=10.0) as sitl,
        Client(19) as c,
    ):
        sitl.start()
        c.wait_heartbeat()
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        c.mav.command_long_send(
            20, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, math.nan, math.nan, HOME.alt_m + 5
        )
        first = c.recv("COMMAND_ACK", cond=lambda m: m.command == M.MAV_CMD_NAV_TAKEOFF)
        assert first.result == M.MAV_RESULT_IN_PROGRESS and sitl.autopilot.state.altitude < 1.0
        final = c.recv("COMMAND_ACK", 10, lambda m: m.command == M.MAV_CMD_NAV_TAKEOFF)
        assert final.result == M.MAV_RESULT_ACCEPTED and final.progress == 100
        assert abs(sitl.autopilot.state.altitude - 5.0) < 0.6


def test_offboard_stream_loss_and_manual_control_walltime():
    """Offboard velocity over MAVLink, then the stream stops: HOLD 0.5 s of simulation time
    after the last setpoint (COM_OF_LOSS_T). MANUAL_CONTROL in POSCTL flies forward.

    Wall time: the client streams at 25 Hz of wall time; at speed-up 2 that is a setpoint every
    0.08 s of simulation time, a 6× margin on the 0.5 s offboard-loss timeout for a busy
    machine (at 5× a 0.1 s scheduling stall already lost the stream)."""
    with running_sitl(instance=2, speedup=2.0) as sitl, Client(2) as c:
        ap, ep = sitl.autopilot, sitl.endpoint
        c.wait_heartbeat()
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert (
            c.command(
                M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, math.nan, math.nan, math.nan, HOME.alt_m + 5
            ).result
            == 0
        )
        assert c.recv("HEARTBEAT", 10, lambda m: m.custom_mode == PX4_HOLD) is not None
        assert c.recv("LOCAL_POSITION_NED", 20, lambda m: abs(m.z + 5) < 0.1) is not None  # settled

        vel_mask = 0b0000_1101_1100_0111  # velocity + yaw

        def setpoints(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                c.mav.set_position_target_local_ned_send(0, 3, 1, M.MAV_FRAME_LOCAL_NED, vel_mask,
                                                         0, 0, 0, 1.5, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
                time.sleep(0.04)  # 25 Hz wall = every 0.2 s of simulation time

        setpoints(0.3)
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED
        setpoints(1.5)
        c.drain()  # telemetry queued while we were only sending
        lp = c.recv("LOCAL_POSITION_NED")
        assert lp.vx == pytest.approx(1.5, abs=0.15) and abs(lp.z + 5) < 0.3
        # Stop streaming: the autopilot falls back to HOLD after COM_OF_LOSS_T.
        assert c.recv("HEARTBEAT", 3, lambda m: m.custom_mode == PX4_HOLD) is not None
        assert c.saw_text("offboard setpoints lost")
        t_loss = float(next(t for t in c.texts if "offboard setpoints lost" in t).split()[0])
        assert t_loss - ep.last_setpoint_t == pytest.approx(0.5, abs=0.009)

        # Manual control: sticks centred (z = 500 holds altitude), POSCTL, then full forward.
        # The stick timeout (COM_RC_LOSS_T 0.5 s → HOLD) is 0.25 s of wall time at speed-up 2:
        # a stall of the streaming thread on a machine at load 7 took the vehicle to HOLD
        # (vx 0). What is tested here is the stick, so its timeout gets 5 s (10× the margin).
        assert c.param_set("COM_RC_LOSS_T", 5.0).param_value == pytest.approx(5.0)

        def sticks(x: int, seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                c.mav.manual_control_send(3, x, 0, 500, 0, 0)
                time.sleep(0.04)

        sticks(0, 0.3)
        assert c.command(M.MAV_CMD_DO_SET_MODE, 1, 3, 0).result == M.MAV_RESULT_ACCEPTED
        assert ap.mode == FlightMode.POSCTL
        sticks(1000, 1.5)
        c.drain()
        lp = c.recv("LOCAL_POSITION_NED")
        vmax = ap.get_param("MPC_VEL_MANUAL")
        assert lp.vx == pytest.approx(vmax, rel=0.1) and abs(lp.vy) < 0.5 and abs(lp.z + 5) < 0.5
        assert ep.stats["manual_dropped"] == 0
        # Sticks stop: manual control lost → HOLD (after the 5 s: 2.5 s of wall time).
        assert c.recv("HEARTBEAT", 15, lambda m: m.custom_mode == PX4_HOLD) is not None
