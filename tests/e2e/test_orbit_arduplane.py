"""The fixed-wing orbit (mission/orbit.py) on ArduPlane's stock parameters, without a flight:
the plan on its 65° roll limit, its climb and sink limits lowered to the envelope's before the
take-off (or the take-off refused with the rule's reason), and the first decision after the
hand-over carrying the orbit's setpoint. A fake link answers PARAM_SET the way ArduPlane does
(PARAM_VALUE with the value stored)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.state import VehicleState
from skyherd.hil.autopilots import ARDUPLANE
from skyherd.mission.flight import Record
from skyherd.mission.orbit import Briefing, OrbitFlight, OrbitMission
from skyherd.mission.orbit_plan import fence_reserve
from skyherd.mission.steps import MissionError
from skyherd.mission.vehicle import VehicleLink
from skyherd.safety.consistency import agreeing_values, check_params
from skyherd.safety.net import SafetyNet, load_net

# Tools/autotest/models/plane.parm and AP_TECS's defaults (the parameters the checks read)
STOCK = {"AIRSPEED_CRUISE": 22.0, "ROLL_LIMIT_DEG": 65.0, "WP_LOITER_RAD": 80.0,
         "TECS_CLMB_MAX": 5.0, "TECS_SINK_MAX": 5.0, "TKOFF_ALT": 50.0}  # fmt: skip
BRIEF = Briefing((0.0, 0.0), team_speed_mps=1.5, team_radius_m=9.375, n_ugvs=3)


class Events:
    def __init__(self):
        self.records = []

    def write(self, record):
        self.records.append(record)


class FakeTel:
    def __init__(self, pos, vel, mode):
        self.pos_ned, self.vel_ned, self.mode = pos, vel, mode
        self.home = None  # no ROI command (it needs home)

    def vehicle_state(self):
        return VehicleState(t=getattr(self, "t", 0.0), pos_ned=self.pos_ned, vel_ned=self.vel_ned,
                            quat=np.array([1.0, 0.0, 0.0, 0.0]), omega_frd=np.zeros(3),
                            accel_frd=np.array([0.0, 0.0, -9.8]), on_ground=False)  # fmt: skip


class FakePlane:
    """What OrbitMission touches of a VehicleLink; PARAM_SET is echoed (or, for names in
    `refuse`, ignored, as ArduPlane ignores a name it does not have)."""

    profile = ARDUPLANE
    target_system = 1

    def __init__(self, params, refuse=()):
        self.t, self.params, self.param_updates = 0.0, dict(params), []
        self.refuse = set(refuse)
        self.sent, self.acks, self.setpoint, self.heartbeat_t = [], {}, None, 0.0
        self.telemetry_t = 0.0
        self.tel = FakeTel(np.array([0.0, 93.0, -92.5]), np.array([22.0, 0.0, 0.0]),
                           FlightMode.OFFBOARD)  # fmt: skip

    def send(self, msg):
        self.sent.append(msg)
        if msg.get_type() == "PARAM_SET":
            name = msg.param_id if isinstance(msg.param_id, str) else msg.param_id.decode()
            name = name.rstrip("\x00")
            if name not in self.refuse:
                value = float(np.float32(msg.param_value))
                self.params[name] = value
                self.param_updates.append((self.t, name, value))

    def command_long(self, command, params, confirmation):
        self.sent.append((command, params))

    feed = VehicleLink.feed  # what arrived → the net, as the companion's VehicleLink does

    def wind_speed(self):
        return None  # the fixed-wing autopilot estimates no wind

    def point_gimbal(self, roi_ned):
        return VehicleLink.point_gimbal(self, roi_ned)  # VehicleLink's, through send()


def _mission():
    events = Events()
    net = SafetyNet.load("fixedwing", events=events)
    lim = net.envelope.spec.limits
    band = (lim.floor_m + lim.margin_m, lim.ceiling_m - lim.margin_m - 15.0)
    m = OrbitMission(net, OrbitFlight(), BRIEF, Record(), fence_reserve(net.envelope.spec), band)
    return m, events


def _run(gen, v, ticks=200):
    for _ in range(ticks):
        try:
            next(gen)
        except StopIteration:
            return
        v.t += 0.1
    raise AssertionError("the phase did not end")


def test_stock_arduplane_climb_and_sink_limits_disagree_and_are_lowered_to_the_envelopes():
    net = load_net("fixedwing")
    spec = net.envelope.spec
    bad = check_params(spec, STOCK)
    assert set(bad) == {"TECS_CLMB_MAX", "TECS_SINK_MAX", "ROLL_LIMIT_DEG"}
    assert (
        "ROLL_LIMIT_DEG = 65 deg: the autopilot may bank past the envelope's attitude"
        in (bad["ROLL_LIMIT_DEG"])
    )
    assert (
        "TECS_CLMB_MAX = 5 m/s: the autopilot may climb faster than the envelope's 2.5"
        in (bad["TECS_CLMB_MAX"])
    )
    fix = agreeing_values(spec, STOCK)
    assert fix == {"TECS_CLMB_MAX": spec.limits.climb_mps, "TECS_SINK_MAX": spec.limits.descent_mps,
                   "ROLL_LIMIT_DEG": 44.0}  # attitude row 50° less 5° of overshoot  # fmt: skip
    assert check_params(spec, {**STOCK, **fix}) == {}
    assert agreeing_values(spec, {**STOCK, **fix}) == {}
    # PX4's fixed-wing names obey the same rule; a multirotor has none to lower
    assert set(check_params(spec, {"FW_T_CLMB_MAX": 5.0, "FW_T_SINK_MAX": 2.0})) == {
        "FW_T_CLMB_MAX"
    }
    assert agreeing_values(load_net("quadrotor").envelope.spec, STOCK) == {}


def test_the_orbit_plans_on_a_65_degree_roll_limit_with_the_bank_it_will_command():
    m, _ = _mission()
    plan = m._plan(FakePlane(STOCK))
    assert plan.team_px <= plan.team_px_max  # refused before: 174 px > 96 px at the roll limit
    assert plan.radius_m == pytest.approx(92.4, abs=0.1) and plan.altitude_m == plan.radius_m
    assert math.degrees(plan.bank_cmd_rad) == pytest.approx(31.4, abs=0.1)
    assert plan.bank_cmd_rad < 0.7 * math.radians(65.0)
    plan35 = m._plan(FakePlane({**STOCK, "ROLL_LIMIT_DEG": 35.0}))  # the turn's circle fits
    assert plan35.radius_m == pytest.approx(23.5**2 / (9.80665 * math.tan(math.radians(24.5))))


def test_the_orbit_sets_the_climb_limits_before_the_takeoff_and_refuses_what_it_cannot_set():
    m, events = _mission()
    v = FakePlane({**STOCK, "WP_LOITER_RAD": 93.0})
    _run(m._agree(v), v)
    assert v.params["TECS_CLMB_MAX"] == 2.5 and v.params["TECS_SINK_MAX"] == 3.0
    assert m.guard.handover() == (True, "")
    said = [(r["consistent"], r["trigger"]) for r in events.records if r["event"] == "params"]
    assert v.params["ROLL_LIMIT_DEG"] == 44.0
    assert said == [(False, "parameters read"), (False, "TECS_CLMB_MAX = 2.5"),
                    (False, "TECS_SINK_MAX = 3.0"), (True, "ROLL_LIMIT_DEG = 44.0")]  # fmt: skip

    m, _ = _mission()  # an autopilot that does not take the value: refused, with the name
    v = FakePlane(STOCK, refuse={"TECS_CLMB_MAX"})
    with pytest.raises(MissionError, match="did not take TECS_CLMB_MAX = 2.5"):
        _run(m._agree(v), v)

    m, _ = _mission()  # a mismatch the companion may not fix: refused with the rule's reason
    v = FakePlane({**STOCK, "ROLL_LIMIT_DEG": 20.0})
    with pytest.raises(MissionError, match="refusing to take off.*ROLL_LIMIT_DEG = 20 deg"):
        _run(m._agree(v), v)


def test_a_parameter_changed_in_flight_is_a_fallback_with_the_reason():
    m, _ = _mission()
    v = FakePlane({**STOCK, "WP_LOITER_RAD": 93.0})
    m.plan = m._plan(v)
    m.net.supervisor.loiter_radius_m = m.plan.radius_m
    _run(m._agree(v), v)
    m._begin_orbit(v)
    m._tick(v)
    assert m.net.mode.value == "ai"
    v.params["TECS_CLMB_MAX"] = 5.0  # someone's PARAM_SET, its PARAM_VALUE seen
    v.param_updates.append((v.t, "TECS_CLMB_MAX", 5.0))
    v.t += 0.2
    m._tick(v)
    assert m.net.mode.value == "fallback"
    assert "TECS_CLMB_MAX = 5 m/s" in m.net.stats.reasons[-1]


def test_the_first_decision_after_the_handover_carries_the_orbits_setpoint():
    """ArduPlane is already in GUIDED after the climb-out, so the hand-over takes one tick:
    the decision period had not passed since the climb-out's last aim, and the net was asked
    to judge no action ("malformed action (no velocity command)", the first fallback seen on
    real ArduPlane)."""
    m, _ = _mission()
    v = FakePlane({**STOCK, "WP_LOITER_RAD": 93.0})
    m.plan = m._plan(v)
    m.net.supervisor.loiter_radius_m = m.plan.radius_m
    _run(m._agree(v), v)
    m._aim(v)  # the climb-out's last aim, a tick before the hand-over
    v.t += 0.1
    m._begin_orbit(v)
    m._tick(v)
    assert m.net.mode.value == "ai", m.net.stats.reasons
    row = m.rec.rows[-1]
    assert row["verdict"] == "accepted" and row["certified"]["pos_ned"] == pytest.approx(
        [0.0, 0.0, -m.plan.altitude_m]
    )
    assert v.setpoint.pos_ned == pytest.approx([0.0, 0.0, -m.plan.altitude_m])


class FakeTransport:
    def __init__(self):
        self.sent = []

    def send(self, data):
        self.sent.append(bytes(data))


class FakeWorldLink:
    def __init__(self):
        self.transport = FakeTransport()

    def send(self, msg):
        pass

    def close(self):
        pass


def test_the_followed_world_plays_the_gimbal_the_autopilot_routes_the_roi_to():
    """Beside a real ArduPlane the world renders the orbit's zoomed camera on its pan-tilt head
    (not the quadrotor's downward one: the companion back-projects with ORBIT_CAMERA), says it
    is the vehicle's gimbal (so ArduPilot's routing forwards commands addressed to it), and
    points the head at a DO_SET_ROI_LOCATION addressed to (system, MAV_COMP_ID_GIMBAL)."""
    from pymavlink.dialects.v20 import ardupilotmega as M

    from skyherd.flight.geo import Home, ned_to_geodetic
    from skyherd.perception.camera import camera_pose, project
    from skyherd.perception.gimbal import ORBIT_CAMERA
    from skyherd.world.follow import FollowWorld
    from skyherd.world.sim import WorldParams

    link = FakeWorldLink()
    w = FollowWorld(link, WorldParams(airframe="fixedwing", camera="roi", lockstep=False))
    assert w.scene.cam is ORBIT_CAMERA
    w._announce_gimbal()
    parser = M.MAVLink(None)
    (hb,) = parser.parse_buffer(link.transport.sent[-1])
    assert (hb.get_srcSystem(), hb.get_srcComponent(), hb.type) == (1, 154, M.MAV_TYPE_GIMBAL)
    w.tel.home = Home(-35.363261, 149.165230, 584.0)
    lat, lon, alt = ned_to_geodetic(w.tel.home, np.array([120.0, -40.0, 0.0]))
    cmd = M.MAVLink_command_long_message(1, 1, M.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, 0,
                                         lat, lon, alt)  # fmt: skip
    assert not w._gimbal_command(cmd)  # addressed to the autopilot itself: not the gimbal's
    cmd.target_component = M.MAV_COMP_ID_GIMBAL
    assert w._gimbal_command(cmd) and w.scene.roi_commands == 1
    assert w.scene.roi_ned == pytest.approx([120.0, -40.0, 0.0], abs=1e-3)
    (ack,) = parser.parse_buffer(link.transport.sent[-1])
    assert ack.get_type() == "COMMAND_ACK" and ack.result == M.MAV_RESULT_ACCEPTED
    # the head looks at the ROI from a banked aircraft: the ROI at the image centre
    state = FakeTel(np.array([0.0, 93.0, -92.5]), np.zeros(3), None).vehicle_state()
    gp = w.scene.camera_pose(state)
    uv, _ = project(ORBIT_CAMERA, camera_pose(ORBIT_CAMERA, gp.pos_ned, gp.quat), w.scene.roi_ned)
    assert uv == pytest.approx(ORBIT_CAMERA.centre_px, abs=1e-6)
    w.close()


def test_the_loiter_radius_is_set_for_the_true_airspeed_and_trimmed_once_per_revolution():
    """ArduPlane flies WP_LOITER_RAD · EAS2TAS²: the orbit sets R / EAS2TAS² (87 for 92.4 m at
    676 m AMSL). Flown wide of R (108 m measured on real ArduPlane about the moving centre),
    one revolution later the setting is scaled by R / mean and PARAM_SET; within tolerance
    nothing is sent."""
    assert ARDUPLANE.loiter_radius_setting(92.4, 584.0 + 92.4) == 87.0
    m, events = _mission()
    v = FakePlane({**STOCK, "WP_LOITER_RAD": 87.0})
    m.plan = m._plan(v)
    m.net.supervisor.loiter_radius_m = m.plan.radius_m
    m.loiter_setting = 87.0
    _run(m._agree(v), v)
    m._begin_orbit(v)
    R = m.plan.radius_m
    period = 2 * math.pi * R / 22.0
    for a in np.arange(0.0, period + 0.2, 0.2):
        th = 22.0 * a / 108.0  # at 22 m/s on a 108 m circle
        v.tel.pos_ned = np.array([108.0 * math.cos(th), 108.0 * math.sin(th), -R])
        v.tel.vel_ned = np.array([-22.0 * math.sin(th), 22.0 * math.cos(th), 0.0])
        v.tel.t = v.heartbeat_t = v.telemetry_t = v.t
        m.net.frame(v.t)  # the camera delivers (a camera that does not is a fallback)
        m._tick(v)
        m._trim_radius(v)
        v.t += 0.2
    assert m.net.mode.value == "ai", m.net.stats.reasons
    assert m.trims == 1 and m.loiter_setting == math.ceil(87.0 * R / 108.0)
    assert v.params["WP_LOITER_RAD"] == m.loiter_setting
    (trim,) = [e for e in events.records if e["event"] == "loiter_radius_trim"]
    assert trim["mean_distance_m"] == pytest.approx(108.0) and trim["set"] == m.loiter_setting
    assert m.guard.handover() == (True, "")  # a narrower hold circle agrees with the envelope
