"""`skyherd fly --connect` (the production companion, free-running on the autopilot's clock,
with the world built around the vehicle) against skyherd's built-in vehicle in both
personalities, standing in for real PX4 and ArduCopter SITL: PX4 (custom modes main/sub,
OFFBOARD, NAV_TAKEOFF in AMSL, the fallback Hold shown as AUTO.LOITER) and ArduCopter
(`--personality ardupilot`: GUIDED, BRAKE, take-off above home, LAND). Two flights in a row on
the same running vehicle, each left disarmed; a camera cut in each puts the net in its
fallback (the autopilot's own hold) and back. What the autopilot did is read back from the
companion's telemetry.tlog through hil.telemetry.

Free-running involves wall time by nature (the autopilot does not wait): the vehicle runs at 1x
(tests/e2e/test_fly_connect.py says why). Instances 70, 71 (ground-station link → 14550)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.mavlink import Personality
from skyherd.hil.telemetry import Telemetry, update_telemetry
from skyherd.scripts.cli import main
from tests.companion_flights import Steps, fly, missions
from tests.mavlink_support import running_sitl


def autopilot_in_tlog(path, system: int) -> Telemetry:
    """The autopilot's messages in a companion's telemetry.tlog, replayed into Telemetry."""
    tel = Telemetry()
    log = mavutil.mavlink_connection(str(path), dialect="ardupilotmega")
    while (m := log.recv_match()) is not None:
        if m.get_srcSystem() == system and m.get_srcComponent() == 1 and m.get_type() != "BAD_DATA":
            update_telemetry(tel, m)
    return tel


def _fly_twice(tmp_path, instance: int, personality: Personality, zenoh_port: int):
    with running_sitl(instance, speedup=1.0, personality=personality) as sitl:
        for flight in range(2):
            t0 = sitl.autopilot.clock.t  # the world's camera cut counts the vehicle's clock
            runs = tmp_path / f"flight{flight}"
            rc = main(["fly", "--connect", f"udpin:127.0.0.1:{14540 + instance}",
                       "--altitude", "6", "--duration", "25", "--cut-camera", f"{t0 + 16:.1f}:3",
                       "--zenoh-port", str(zenoh_port), "--instance", str(instance - 60),
                       "--timeout", "600", "--no-record", "--runs-dir", str(runs)])  # fmt: skip
            (run,) = runs.iterdir()
            assert rc == 0, (run / "summary.md").read_text()
            comp = json.loads((run / "companion.json").read_text())
            assert comp["outcome"] == "completed" and comp["yielded"] is None
            tel = autopilot_in_tlog(run / "telemetry.tlog", 1 + instance)
            assert not tel.armed and not sitl.autopilot.armed
            assert sitl.autopilot.mode is not FlightMode.OFFBOARD  # left in a normal mode
            events = [json.loads(x) for x in (run / "events.jsonl").read_text().splitlines()]
            switches = [(e["from"], e["to"]) for e in events if e["event"] == "switch"]
            assert ("ai", "fallback") in switches, switches  # the camera cut ...
            assert switches[-1][1] == "ai", switches  # ... and back to the AI
            yield tel, comp, sitl


@pytest.mark.timeout(600)
@pytest.mark.slow
def test_fly_connect_flies_the_builtin_px4_personality_twice_walltime(tmp_path):
    for tel, comp, sitl in _fly_twice(tmp_path, 70, Personality.PX4, 7463):
        assert tel.profile.name == "PX4"
        names = [n for _, n in tel.modes]
        assert {"AUTO.TAKEOFF", "OFFBOARD", "AUTO.LOITER", "AUTO.LAND"} <= set(names), names
        assert tel.mode_name == "AUTO.LOITER"  # PX4's end: Hold, ready to arm again
        assert comp["mode_requests"] >= 2  # the fallback's Hold and OFFBOARD back
        takeoffs = sitl.endpoint.rx_commands[M.MAV_CMD_NAV_TAKEOFF]
    assert takeoffs == 2


@pytest.mark.timeout(600)
@pytest.mark.slow
def test_fly_connect_flies_the_builtin_ardupilot_personality_twice_walltime(tmp_path):
    for tel, _comp, sitl in _fly_twice(tmp_path, 71, Personality.ARDUPILOT, 7464):
        assert tel.profile.name == "ArduCopter"
        names = [n for _, n in tel.modes]
        assert {"GUIDED", "BRAKE", "LAND"} <= set(names) and "LOITER" not in names, names
        assert sitl.autopilot.mode is FlightMode.LAND  # ArduCopter's end: LAND, disarmed


def test_update_telemetry_is_a_pure_step():
    """Messages fed one by one, as the companion's VehicleLink applies them."""
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
    assert tel.mode_name == "BRAKE" and tel.t == 2.0 and tel.modes == [(0.0, "BRAKE")]
    assert np.allclose(tel.pos_ned, [3.0, 0.0, -10.0])  # about home, not the EKF origin
    assert tel.quat is not None and abs(tel.quat[0] - np.cos(0.5) * np.cos(0.05)) < 1e-3
    assert tel.landed_state == M.MAV_LANDED_STATE_ON_GROUND  # disarmed: derived, no ESS
    with pytest.raises(ValueError, match="not flown"):
        update_telemetry(Telemetry(), M.MAVLink_heartbeat_message(
            M.MAV_TYPE_GROUND_ROVER, M.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0, 0, 3))  # fmt: skip


@pytest.mark.timeout(600)
@pytest.mark.parametrize(
    ("instance", "personality", "end_mode"),
    [(72, Personality.PX4, "AUTO.LOITER"), (73, Personality.ARDUPILOT, "LAND")],
)
@pytest.mark.slow
def test_the_real_autopilot_tests_missions_on_the_builtin_stand_ins(
    instance, personality, end_mode
):
    """tests/e2e/test_autopilots_real.py's copter missions (two in a row on one running vehicle,
    the net's fallback and back in each) on the built-in vehicle in the same personality:
    what `make test-autopilots` flies, checked here where no PX4 / ArduPilot is built."""
    out: dict = {}
    with running_sitl(instance, speedup=5.0, personality=personality) as sitl:
        sitl.autopilot.set_param("COM_OF_LOSS_T", 10.0)  # 2 s of wall: no failsafe from load
        v = fly(f"udpin:127.0.0.1:{14540 + instance}", Steps(),
                missions(6.0, [8.0, 4.0, -6.0], 1.0, 2, out))  # fmt: skip
        assert not sitl.autopilot.armed
    assert out == {"yielded_0": None, "armed_0": False, "yielded_1": None, "armed_1": False}
    names = [n for _, n in v.tel.modes]
    fallback = {Personality.PX4: "AUTO.LOITER", Personality.ARDUPILOT: "BRAKE"}[personality]
    assert names.count(fallback) >= 2 and v.tel.mode_name == end_mode, names
