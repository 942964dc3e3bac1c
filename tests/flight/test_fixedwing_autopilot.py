"""Fixed-wing autopilot on JSBSim: straight and level, loiter, protections, modes, bad input."""

import math

import numpy as np
import pytest

from skyherd.flight.autopilot_api import (
    FlightMode,
    LandedState,
    MissionCommand,
    MissionItem,
    Setpoint,
)
from skyherd.flight.fixedwing.autopilot import FixedWingAutopilot, Phase
from skyherd.flight.geo import GRAVITY


def fly(ap, seconds, each=None):
    for _ in range(round(seconds / ap.control_dt)):
        ap.step()
        s = ap.state
        if each is not None:
            each(s)
    return ap.state


def stream(ap, sp, seconds, each=None):
    """Fly while streaming `sp` at 10 Hz (the clock's time)."""
    n = round(0.1 / ap.control_dt)
    for i in range(round(seconds / ap.control_dt)):
        if i % n == 0:
            assert ap.set_offboard_setpoint(sp).ok
        ap.step()
        s = ap.state
        if each is not None:
            each(s)


def airborne(alt=60.0, v=24.0, heading=0.0):
    ap = FixedWingAutopilot()
    ap.start_in_air(alt, v, heading)
    return ap


def test_autopilot_straight_and_level_holds_60s():
    """Issue 7 with the autopilot closing the loops: ±2 m, ±1 m/s for 60 s."""
    ap = airborne(60.0, 24.0)
    sp = Setpoint(vel_ned=np.array([24.0, 0.0, 0.0]))
    assert ap.set_offboard_setpoint(sp).ok
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    h, v, yaw = [], [], []
    stream(
        ap,
        sp,
        60.0,
        lambda s: (h.append(s.altitude), v.append(ap.airspeed), yaw.append(s.euler[2])),
    )
    assert max(abs(x - 60.0) for x in h) < 2.0
    assert max(abs(x - 24.0) for x in v) < 1.0
    assert max(abs(y) for y in yaw) < math.radians(3.0)
    assert ap.mode == FlightMode.OFFBOARD


def test_loiter_holds_radius_and_altitude():
    """Issue 7: HOLD is a loiter circle; radius ±10 %, altitude ±5 m in calm air."""
    ap = airborne(60.0, 24.0)
    assert ap.set_mode(FlightMode.HOLD).ok
    r0 = ap.loiter_radius
    v, phi = ap.p("FW_AIRSPD_TRIM"), math.radians(ap.p("FW_R_LIM"))
    # Radius from turn performance: R = V^2 / (g tan(0.7 phi_max)).
    assert r0 == pytest.approx(v * v / (GRAVITY * math.tan(0.7 * phi)), rel=1e-9)
    h, d, bank = [], [], []
    fly(ap, 40.0, lambda s: h.append(s.altitude))  # entering the circle
    c = ap.loiter_center

    def rec(s):
        h.append(s.altitude)
        d.append(float(np.hypot(*(s.pos_ned[:2] - c))))
        bank.append(s.euler[0])

    fly(ap, 120.0, rec)  # more than two laps (one lap ≈ 2πR/V ≈ 34 s)
    assert max(abs(x - 60.0) for x in h) < 5.0
    assert max(abs(x - r0) for x in d) < 0.10 * r0
    # Steady coordinated turn: tan(bank) = V^2 / (g R) (closed form), within 2 deg.
    vg = ap.airspeed
    assert np.mean(bank) == pytest.approx(math.atan(vg * vg / (GRAVITY * r0)), abs=math.radians(2))
    assert ap.mode == FlightMode.HOLD and ap.landed_state == LandedState.IN_AIR


def test_offboard_velocity_turns_and_climbs_then_times_out_to_loiter():
    ap = airborne(60.0, 24.0)
    sp = Setpoint(vel_ned=np.array([0.0, 24.0, -1.5]))  # east, climbing 1.5 m/s
    stream(ap, sp, 0.5)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    stream(ap, sp, 30.0)
    s = ap.state
    assert abs(s.euler[2] - math.pi / 2) < math.radians(5)
    assert s.altitude > 60.0 + 1.5 * 30.0 - 12.0
    # Setpoints stop: after COM_OF_LOSS_T (0.5 s) the aircraft holds (loiters).
    fly(ap, 0.4)
    assert ap.mode == FlightMode.OFFBOARD
    fly(ap, 0.2)
    assert ap.mode == FlightMode.HOLD and ap.phase == Phase.LOITER


def test_offboard_position_loiters_about_the_point():
    ap = airborne(60.0, 24.0)
    tgt = np.array([600.0, 300.0, -70.0])
    stream(ap, Setpoint(pos_ned=tgt), 0.5)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    d = []
    stream(
        ap, Setpoint(pos_ned=tgt), 150.0, lambda s: d.append(np.hypot(*(s.pos_ned[:2] - tgt[:2])))
    )
    tail = d[-2000:]
    assert max(abs(x - ap.loiter_radius) for x in tail) < 0.1 * ap.loiter_radius
    assert abs(ap.state.altitude - 70.0) < 3.0


def test_stall_protection_engine_idle_glide_keeps_flying_speed():
    """With the throttle capped at idle, TECS trades height for speed: no stall."""
    ap = airborne(150.0, 24.0)
    assert ap.set_param("FW_THR_MAX", 0.0).ok
    v, h = [], []
    fly(ap, 40.0, lambda s: (v.append(ap.airspeed), h.append(s.altitude)))
    assert min(v) > ap.p("FW_AIRSPD_MIN") - 1.5 > ap.p("FW_AIRSPD_STALL")
    assert h[-1] < 150.0 - 20.0  # it is gliding down


def test_speed_demands_are_clamped_to_the_envelope():
    ap = airborne(80.0, 24.0)
    slow = Setpoint(vel_ned=np.array([10.0, 0.0, 0.0]))  # below the minimum airspeed
    stream(ap, slow, 0.5)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    v = []
    stream(ap, slow, 30.0, lambda s: v.append(ap.airspeed))
    assert min(v) > ap.p("FW_AIRSPD_MIN") - 1.0
    fast = Setpoint(vel_ned=np.array([60.0, 0.0, 0.0]))
    v.clear()
    stream(ap, fast, 40.0, lambda s: v.append(ap.airspeed))
    assert max(v) < ap.p("FW_AIRSPD_MAX") + 1.0


def test_bank_limit_shrinks_near_the_stall():
    ap = airborne()
    vs = ap.p("FW_AIRSPD_STALL")
    lim = math.radians(ap.p("FW_R_LIM"))
    assert ap._bank_limit(40.0) == pytest.approx(lim)
    # Load factor 1/cos(phi) keeps the stall speed 15 % below the airspeed.
    v = 22.0
    assert math.cos(ap._bank_limit(v)) == pytest.approx((1.15 * vs / v) ** 2)
    assert ap._bank_limit(18.0) == pytest.approx(math.radians(5.0))


def test_manual_sticks_drive_surfaces():
    ap = airborne()
    assert ap.set_mode(FlightMode.MANUAL).ok
    assert ap.set_manual_control(0.0, 0.4, 0.6, 0.0).ok
    fly(ap, 1.0)
    assert ap.state.omega_frd[0] > 0.05 and ap.state.euler[0] > math.radians(5)
    assert ap.set_mode(FlightMode.ALTCTL).ok
    assert ap.set_manual_control(0.0, 0.0, 0.5, 0.0).ok
    fly(ap, 15.0)
    assert abs(ap.state.euler[0]) < math.radians(5)


def test_bad_requests_are_refused_with_reasons():
    ap = FixedWingAutopilot()
    assert not ap.takeoff().ok  # not armed
    assert not ap.set_mode(FlightMode.MISSION).ok  # no mission
    assert not ap.set_mode(FlightMode.OFFBOARD).ok  # no setpoints
    assert not ap.set_offboard_setpoint(Setpoint(pos_ned=np.array([np.nan, 0, 0]))).ok
    assert not ap.set_offboard_setpoint(Setpoint(yaw=1.0)).ok
    assert not ap.set_manual_control(float("nan"), 0, 0, 0).ok
    assert not ap.set_param("FW_AIRSPD_MIN", float("nan")).ok
    assert not ap.set_param("FW_R_LIM", 89.0).ok
    assert not ap.set_param("NO_SUCH", 1.0).ok
    bad = [MissionItem(MissionCommand.WAYPOINT, np.array([0.0, np.inf, -50.0]))]
    assert not ap.set_mission(bad).ok
    assert not ap.reposition(np.array([1.0, 2.0])).ok
    assert not ap.set_mission_current(3).ok
    assert not ap.land().ok or ap.state.on_ground
    fly(ap, 0.2)
    assert ap.state.on_ground and not ap.armed
    a = airborne()
    assert not a.arm().ok or a.armed  # already armed in the air: accepted as a no-op
    assert not a.disarm().ok  # flying
    assert not a.takeoff(float("nan")).ok


def test_deterministic():
    def run():
        ap = airborne()
        ap.set_mode(FlightMode.HOLD)
        fly(ap, 10.0)
        return ap.state

    a, b = run(), run()
    assert np.array_equal(a.pos_ned, b.pos_ned) and np.array_equal(a.quat, b.quat)


def test_loiter_in_a_5ms_crosswind():
    """L1 flies the circle over the ground: the radius holds with wind drifting the air mass."""
    ap = airborne(60.0, 24.0)
    ap.model.set_wind(np.array([0.0, 5.0, 0.0]))
    assert ap.set_mode(FlightMode.HOLD).ok
    fly(ap, 40.0)
    c, r0 = ap.loiter_center, ap.loiter_radius
    d, h = [], []
    fly(ap, 80.0, lambda s: (d.append(np.hypot(*(s.pos_ned[:2] - c))), h.append(s.altitude)))
    assert max(abs(x - r0) for x in d) < 0.10 * r0
    assert max(abs(x - 60.0) for x in h) < 5.0


def test_repeated_commands_are_idempotent():
    """MAVLink clients retry commands: a second land / RTL / hold must not restart anything."""
    ap = airborne(60.0, 24.0)
    assert ap.set_mode(FlightMode.HOLD).ok
    c = ap.loiter_center
    fly(ap, 5.0)
    assert ap.set_mode(FlightMode.HOLD).ok and np.array_equal(ap.loiter_center, c)
    assert ap.return_to_launch().ok
    fly(ap, 5.0)
    phase = ap.phase
    assert ap.return_to_launch().ok and ap.phase == phase and ap.mode == FlightMode.RTL
    assert ap.land().ok
    fly(ap, 30.0)
    phase, center = ap.phase, ap.loiter_center
    assert phase in (Phase.LAND_DESCEND, Phase.LAND_FINAL)
    assert ap.land().ok and ap.phase == phase and np.array_equal(ap.loiter_center, center)


def test_force_disarm_in_flight_stops_the_engine_and_never_crashes_the_code():
    ap = airborne(60.0, 24.0)
    assert not ap.disarm().ok
    assert ap.disarm(force=True).ok and not ap.armed
    assert ap.model.get_property("propulsion/engine/set-running") == 0.0
    fly(ap, 2.0)
    assert ap.model.get_property("propulsion/engine/power-hp") <= 0.0  # only friction
    fly(ap, 60.0)  # unpowered, surfaces neutral: it comes down somewhere, the code keeps going
    s = ap.state
    assert s.on_ground and all(np.all(np.isfinite(v)) for v in (s.pos_ned, s.vel_ned, s.quat))
    assert ap.landed_state == LandedState.ON_GROUND


def test_land_during_the_takeoff_roll_aborts_on_the_runway():
    ap = FixedWingAutopilot()
    assert ap.arm().ok and ap.takeoff(40.0).ok
    fly(ap, 8.0)
    assert ap.phase == Phase.TAKEOFF_ROLL and ap.airspeed > 5.0
    assert ap.land().ok and ap.phase == Phase.ROLLOUT
    assert ap.model.surfaces.throttle == 1.0  # the last take-off command, until the next step
    fly(ap, 30.0)
    s = ap.state
    assert not ap.armed and s.on_ground and np.linalg.norm(s.vel_ned) < 0.3
    assert abs(s.pos_ned[1]) < 3.0 and s.pos_ned[0] < 150.0


def test_mission_replaced_in_flight_restarts_and_empty_mission_holds():
    ap = airborne(60.0, 24.0)
    far = [MissionItem(MissionCommand.WAYPOINT, np.array([3000.0, 0.0, -60.0]))]
    assert ap.set_mission(far).ok and ap.set_mode(FlightMode.MISSION).ok
    fly(ap, 5.0)
    west = [MissionItem(MissionCommand.WAYPOINT, np.array([0.0, -800.0, -60.0]))]
    assert ap.set_mission(west).ok
    assert ap.mode == FlightMode.MISSION and np.allclose(ap._b, [0.0, -800.0])
    fly(ap, 60.0)
    assert ap.mission_progress.reached == [0]
    assert ap.set_mission([]).ok and ap.mode == FlightMode.HOLD and ap.phase == Phase.LOITER


def test_land_far_from_home_lands_straight_ahead():
    """Beyond 1500 m from home LAND picks a touchdown point ahead on the present course."""
    ap = airborne(60.0, 24.0, heading=math.pi / 2)
    sp = Setpoint(vel_ned=np.array([0.0, 24.0, 0.0]))  # east
    assert ap.set_offboard_setpoint(sp).ok and ap.set_mode(FlightMode.OFFBOARD).ok
    stream(ap, sp, 75.0)
    assert ap.land().ok
    td = ap._runway.point.copy()
    assert td[1] > ap.state.pos_ned[1] + 400.0 and abs(ap._runway.heading - math.pi / 2) < 0.05
    touch = []
    fly(ap, 150.0, lambda s: touch.append(s.pos_ned.copy()) if ap.phase == Phase.ROLLOUT else None)
    assert not ap.armed and ap.state.on_ground
    assert abs(touch[0][0] - td[0]) < 10.0 and -50.0 < touch[0][1] - td[1] < 100.0
