"""The companion link against skyherd's built-in vehicle (real endpoint, real UDP sockets, the
simulated multirotor), with both personalities: PX4 (custom modes main/sub, OFFBOARD,
NAV_TAKEOFF in AMSL) and ArduCopter (`--personality ardupilot`: GUIDED, BRAKE, take-off above
home). Two missions fly in a row on the same running vehicle, each left disarmed; every limit
counts the vehicle's simulation clock. Instances 70-74.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as M

from flight.autopilot_api import FlightMode
from flight.mavlink import Personality
from hil.client import ClientTimeout, VehicleClient, Yielded, update_telemetry
from hil.link import MavlinkLink
from hil.session import TRACK_COLUMNS, FlightSession
from runio import RunFolder
from tests.mavlink_support import running_sitl


def _fly_twice(tmp_path, instance: int, personality: Personality):
    with running_sitl(instance, speedup=5.0, personality=personality) as sitl:
        link = MavlinkLink.open(f"udpin:127.0.0.1:{14540 + instance}")
        with VehicleClient(link) as c:
            tel = c.telemetry
            c.wait_connected()
            # offboard loss after 10 s of sim time (2 s wall): no failsafe from a busy machine
            assert c.set_param("COM_OF_LOSS_T", 10.0) == 10.0
            if personality is Personality.PX4:  # the parameter by its profile key, in SI
                assert c.param_si("offboard_loss_timeout") == 10.0
            for _mission in range(2):
                run = RunFolder("fly", root=tmp_path)
                fs = FlightSession(c, run.metrics(TRACK_COLUMNS), ["x"] * 6, timeout=120)
                fs.connect_arm_takeoff(6.0)
                fs.offboard(6.0)
                fs.hold_target = np.array([8.0, 0.0, -6.0])
                c.wait_until(lambda f=fs: np.linalg.norm(tel.pos_ned - f.hold_target) < 0.5, 60,
                             "the target", vehicle_s=30)  # fmt: skip
                fs.set_mode(c.profile.fallback_mode)  # the safety net's fallback
                shown = tel.mode_name
                fs.set_mode(c.profile.ai_mode)
                fs.land()
                fs.close()
                assert not c.error, c.error
                log = json.loads((run.path / "autopilot.json").read_text())
                assert log["autopilot"]["name"] == c.profile.name and log["modes"]
                assert all(m["requested"] for m in log["modes"])
                assert not tel.armed and not sitl.autopilot.armed and not c.streaming
                assert sitl.autopilot.mode is not FlightMode.OFFBOARD  # left in a normal mode
                yield c, shown, sitl


def test_builtin_px4_personality_flies_two_missions(tmp_path):
    for c, fallback_name, sitl in _fly_twice(tmp_path, 70, Personality.PX4):
        assert c.profile.name == "PX4" and fallback_name == "AUTO.LOITER"
        assert c.telemetry.unrequested_mode_change == 0
        assert c.telemetry.mode_name == "AUTO.LOITER"  # PX4 end: Hold, ready to arm again
        assert sitl.endpoint.rx_commands[M.MAV_CMD_NAV_TAKEOFF] >= 1


def test_builtin_ardupilot_personality_flies_two_missions(tmp_path):
    for c, fallback_name, sitl in _fly_twice(tmp_path, 71, Personality.ARDUPILOT):
        assert c.profile.name == "ArduCopter (skyherd built-in)"
        assert fallback_name == "BRAKE"  # the hold asked for, shown as ArduCopter shows it
        assert sitl.autopilot.mode is FlightMode.LAND
        assert c.telemetry.unrequested_mode_change == 0


def test_builtin_vehicle_offboard_loss_is_an_unrequested_mode_change():
    """The built-in vehicle's own failsafe (offboard setpoints lost → HOLD) is the autopilot
    taking over: the client yields, refuses to switch back and stops streaming."""
    with running_sitl(72, speedup=5.0) as sitl:
        link = MavlinkLink.open("udpin:127.0.0.1:14612")
        with VehicleClient(link) as c:
            tel = c.telemetry
            c.wait_ready(timeout=60)
            c.set_param("COM_OF_LOSS_T", 5.0)  # 1 s of wall time: only the deliberate loss counts
            assert 191 == link.codec.tx.srcComponent
            c.run_steps(c.profile.takeoff_steps(4.0, c.home_amsl()), 60, authority=False)
            c.run_steps(c.profile.handover_steps(), 60)
            assert tel.mode is FlightMode.OFFBOARD
            c.stop_setpoints()  # the stream stops without a mode request: PX4 holds
            with pytest.raises(Yielded, match="AUTO.LOITER"):
                c.wait_until(lambda: False, 60, "the flight", vehicle_s=20)
            with pytest.raises(Yielded):
                c.set_mode(FlightMode.OFFBOARD)
            assert tel.unrequested_mode_change == 1 and sitl.autopilot.mode is FlightMode.HOLD
            with pytest.raises(Yielded):  # not even to land: the autopilot has it
                c.run_steps(c.profile.land_steps(), 60)
            assert tel.armed and sitl.autopilot.mode is FlightMode.HOLD


def test_update_telemetry_is_a_pure_step_without_the_receive_thread():
    """A single-threaded caller feeds messages one by one (as the tick-driven companion)."""
    from hil.client import Telemetry

    mav = M.MAVLink(None, srcSystem=1, srcComponent=1)
    tel = Telemetry()
    hb = M.MAVLink_heartbeat_message(M.MAV_TYPE_QUADROTOR, M.MAV_AUTOPILOT_ARDUPILOTMEGA,
                                     M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 17, M.MAV_STATE_STANDBY, 3)  # fmt: skip
    for m in (hb, M.MAVLink_attitude_message(1500, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0),
              M.MAVLink_home_position_message(-353632610, 1491652300, 584000, 1.0, 2.0, -0.5,
                                              [1, 0, 0, 0], 0, 0, 0),
              M.MAVLink_local_position_ned_message(2000, 4.0, 2.0, -10.5, 0.0, 0.0, 0.0)):  # fmt: skip
        update_telemetry(tel, M.MAVLink(None).decode(bytearray(m.pack(mav))))
    assert tel.profile.name == "ArduCopter" and tel.mode is FlightMode.HOLD
    assert tel.mode_name == "BRAKE" and tel.t == 2.0
    assert np.allclose(tel.pos_ned, [3.0, 0.0, -10.0])  # about home, not the EKF origin
    assert tel.quat is not None and abs(tel.quat[0] - np.cos(0.5) * np.cos(0.05)) < 1e-3
    assert tel.landed_state == M.MAV_LANDED_STATE_ON_GROUND  # disarmed: derived, no ESS
    with pytest.raises(ValueError, match="not flown"):
        update_telemetry(Telemetry(), M.MAVLink_heartbeat_message(
            M.MAV_TYPE_GROUND_ROVER, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0, 3))  # fmt: skip


def test_readiness_names_what_is_missing_when_nothing_answers():
    link = MavlinkLink.open("udpin:127.0.0.1:14613")
    with VehicleClient(link) as c:
        c.options = type(c.options)(silence_s=0.5)
        with pytest.raises(ClientTimeout, match="heartbeat|no message"):
            c.wait_ready(timeout=1.0)


def test_yielding_can_be_turned_off_but_the_change_stays_visible():
    """ClientOptions(yield_to_autopilot=False): a mission that re-engages by design (on the
    built-in vehicle) still sees the autopilot's own change counted, and may switch back."""
    from hil.client import ClientOptions

    with running_sitl(73, speedup=5.0) as sitl:
        link = MavlinkLink.open("udpin:127.0.0.1:14613")
        with VehicleClient(link, options=ClientOptions(yield_to_autopilot=False)) as c:
            tel = c.telemetry
            c.wait_ready(timeout=60)
            c.set_param("COM_OF_LOSS_T", 5.0)
            c.run_steps(c.profile.takeoff_steps(4.0, c.home_amsl()), 60, authority=False)
            c.run_steps(c.profile.handover_steps(), 60)
            c.stop_setpoints()
            c.wait_until(lambda: tel.mode is FlightMode.HOLD, 60, "the failsafe", vehicle_s=20)
            assert tel.unrequested_mode_change == 1 and "AUTO.LOITER" in tel.yielded
            c.run_steps(c.profile.handover_steps(), 60)  # back to OFFBOARD: allowed here
            assert sitl.autopilot.mode is FlightMode.OFFBOARD
            c.run_steps(c.profile.land_steps(), 60)
