"""Multirotor autopilot: measured step responses, modes, failsafes, bad input."""

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
from skyherd.flight.clock import SimClock
from skyherd.flight.multirotor import MultirotorAutopilot
from skyherd.flight.quadrotor import WindModel


def fly(ap, seconds, each=None):
    """Step for `seconds`; call each(ap, state) per step; return (t, pos) arrays."""
    n = round(seconds / ap.control_dt)
    ts, ps = np.empty(n), np.empty((n, 3))
    for k in range(n):
        if each is not None:
            each(ap, ap.state)
        ap.step()
        s = ap.state
        ts[k], ps[k] = s.t, s.pos_ned
    return ts, ps


def airborne(alt=10.0, settle=12.0):
    ap = MultirotorAutopilot()
    assert ap.arm().ok and ap.takeoff(alt).ok
    fly(ap, settle)
    assert ap.mode == FlightMode.HOLD and not ap.state.on_ground
    return ap


def settling_time(t, y, target, band):
    """First time after which |y − target| stays within band (inf if never)."""
    out = np.nonzero(np.abs(y - target) > band)[0]
    return t[0] if len(out) == 0 else (t[out[-1] + 1] if out[-1] + 1 < len(t) else math.inf)


def test_takeoff_climb_10m_settles_within_5pct_under_8s_without_overshoot():
    ap = MultirotorAutopilot()
    assert ap.arm().ok and ap.takeoff(10.0).ok
    t, p = fly(ap, 15.0)
    alt = -p[:, 2]
    ts = settling_time(t, alt, 10.0, 0.5)
    overshoot = alt.max() - 10.0
    assert ts < 8.0, ts
    assert overshoot < 1.0, overshoot
    assert ap.mode == FlightMode.HOLD and ap.landed_state == LandedState.IN_AIR


def test_climb_step_10m_in_air_settles_within_5pct_under_8s():
    ap = airborne(10.0)
    t0 = ap.clock.t
    target = np.array([0.0, 0.0, -20.0])
    ap.set_offboard_setpoint(Setpoint(pos_ned=target))
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    t, p = fly(ap, 12.0, lambda a, s: a.set_offboard_setpoint(Setpoint(pos_ned=target)))
    alt = -p[:, 2]
    assert settling_time(t, alt, 20.0, 0.5) - t0 < 8.0
    assert alt.max() - 20.0 < 1.0


def test_hover_holds_within_20cm_for_60s():
    ap = airborne(10.0, settle=15.0)
    ref = ap.state.pos_ned.copy()
    _, p = fly(ap, 60.0)
    err = np.linalg.norm(p - ref, axis=1).max()
    assert err < 0.2, err
    assert np.linalg.norm(p[-1] - [0, 0, -10]) < 0.2


def test_hover_in_wind_and_gusts_holds_within_20cm_for_60s():
    wind = WindModel(mean_ned=(5.0, -3.0, 0.0), gust_std=1.0, gust_tau=2.0, seed=1)
    ap = MultirotorAutopilot(wind=wind)
    assert ap.arm().ok and ap.takeoff(10.0).ok
    fly(ap, 15.0)
    _, p = fly(ap, 60.0)
    err = np.linalg.norm(p - [0.0, 0.0, -10.0], axis=1).max()
    assert err < 0.2, err
    assert np.linalg.norm(ap.wind_ned[:2]) > 2.0  # the wind really blew
    roll, pitch, _ = ap.state.euler
    assert math.hypot(roll, pitch) > math.radians(1.0)  # leaning into it


def test_north_step_20m_settles_without_oscillation():
    ap = airborne(10.0)
    t0 = ap.clock.t
    target = np.array([20.0, 0.0, -10.0])
    ap.set_offboard_setpoint(Setpoint(pos_ned=target))
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    t, p = fly(ap, 15.0, lambda a, s: a.set_offboard_setpoint(Setpoint(pos_ned=target)))
    e = p[:, 0] - 20.0
    overshoot = e.max()
    significant = np.sign(e[np.abs(e) > 0.05])  # crossings of a ±5 cm band
    crossings = int(np.sum(significant[1:] != significant[:-1]))
    assert overshoot < 0.4, overshoot  # < 2 %
    assert crossings <= 1, crossings
    assert settling_time(t, p[:, 0], 20.0, 1.0) - t0 < 6.0
    assert abs(e[-1]) < 0.05  # no slow integrator tail
    assert np.abs(p[:, 1]).max() < 0.1 and np.abs(p[:, 2] + 10).max() < 0.5


def test_offboard_velocity_and_loss_to_hold_after_half_a_second():
    ap = airborne(10.0)
    sp = Setpoint(vel_ned=np.array([0.0, 3.0, 0.0]))
    assert ap.set_mode(FlightMode.OFFBOARD).ok is False  # no stream yet
    ap.set_offboard_setpoint(sp)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    # 50 Hz stream for 4 s
    for k in range(1000):
        if k % 5 == 0:
            ap.set_offboard_setpoint(sp)
        ap.step()
    assert abs(ap.state.vel_ned[1] - 3.0) < 0.1
    t_last = ap.clock.t - 4 * ap.control_dt  # last setpoint was 5 steps back at most
    while ap.mode == FlightMode.OFFBOARD:
        ap.step()
    t_hold = ap.clock.t
    assert 0.5 <= t_hold - t_last <= 0.5 + 2 * 5 * ap.control_dt
    assert "offboard setpoints lost" in " ".join(ap.drain_status())
    fly(ap, 10.0)
    assert np.linalg.norm(ap.state.vel_ned) < 0.1  # holding


def test_mission_four_waypoints_reached_in_order_then_lands_and_disarms():
    ap = MultirotorAutopilot()
    wps = [(25.0, 0.0, -15.0), (25.0, 25.0, -15.0), (0.0, 25.0, -20.0), (0.0, 0.0, -15.0)]
    items = [MissionItem(MissionCommand.TAKEOFF, np.array([0.0, 0.0, -15.0]))]
    items += [MissionItem(MissionCommand.WAYPOINT, np.array(w), hold_s=1.0) for w in wps]
    items += [MissionItem(MissionCommand.LAND, np.array([3.0, 3.0, 0.0]))]
    assert ap.set_mode(FlightMode.MISSION).ok is False  # nothing uploaded
    assert ap.set_mission(items).ok
    assert ap.set_mode(FlightMode.MISSION).ok and ap.arm().ok
    reached, currents = [], []

    def watch(a, s):
        reached.extend(a.mission_progress.reached)
        a.mission_progress.reached.clear()
        currents.append(a.mission_progress.current)

    _, p = fly(ap, 110.0, watch)
    assert reached == [0, 1, 2, 3, 4, 5]
    assert currents == sorted(currents)
    assert ap.mission_progress.finished
    for w in wps:  # each waypoint actually visited
        assert np.linalg.norm(p - w, axis=1).min() < 2.0
    assert np.linalg.norm(ap.state.pos_ned - [3.0, 3.0, 0.0]) < 0.5
    assert not ap.armed and ap.landed_state == LandedState.ON_GROUND


def test_rtl_climbs_returns_and_lands_within_1m_of_home():
    ap = airborne(10.0)
    assert ap.reposition(np.array([40.0, -30.0, -12.0])).ok
    fly(ap, 20.0)
    assert np.linalg.norm(ap.state.pos_ned - [40, -30, -12]) < 0.5
    assert ap.return_to_launch().ok and ap.mode == FlightMode.RTL
    _, p = fly(ap, 80.0)
    assert -p[:, 2].min() >= 30.0 - 1.0  # climbed to RTL_RETURN_ALT first
    assert math.hypot(*ap.state.pos_ned[:2]) < 1.0
    assert ap.state.on_ground and not ap.armed


def test_land_detects_touchdown_and_auto_disarms():
    ap = airborne(5.0)
    assert ap.land().ok and ap.landed_state == LandedState.LANDING
    t, p = fly(ap, 15.0)
    touchdown = t[np.argmax(p[:, 2] >= 0.0)]
    assert not ap.armed and "auto-disarmed" in " ".join(ap.drain_status())
    assert ap.state.pos_ned[2] == 0.0 and touchdown < ap.clock.t - 2.0


def test_arming_rules():
    ap = MultirotorAutopilot(start_pos_ned=(0.0, 0.0, -20.0))
    assert not ap.on_ground
    assert not ap.arm().ok  # in the air
    assert not ap.takeoff(5.0).ok  # not armed
    assert ap.arm(force=True).ok
    fly(ap, 2.0)
    assert not ap.disarm().ok and ap.armed  # in flight
    assert ap.disarm(force=True).ok and not ap.armed
    ap2 = MultirotorAutopilot()
    assert ap2.arm().ok and ap2.arm().ok  # idempotent
    assert not ap2.return_to_launch().ok  # landed
    fly(ap2, 11.0)  # COM_DISARM_PRFLT = 10 s without takeoff
    assert not ap2.armed


def test_nan_and_out_of_range_requests_refused_without_state_change():
    ap = airborne(10.0)
    target = np.array([5.0, 0.0, -10.0])
    ap.set_offboard_setpoint(Setpoint(pos_ned=target))
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    bad = [
        Setpoint(pos_ned=np.array([np.nan, 0.0, -10.0])),
        Setpoint(vel_ned=np.array([0.0, np.inf, 0.0])),
        Setpoint(pos_ned=target, yaw=float("nan")),
        Setpoint(pos_ned=np.array([1e9, 0.0, 0.0])),
        Setpoint(),
    ]
    for b in bad:
        r = ap.set_offboard_setpoint(b)
        assert not r.ok and r.reason
    assert not ap.takeoff(float("nan")).ok
    assert not ap.reposition(np.array([0.0, np.nan, -5.0])).ok
    assert not ap.set_manual_control(np.nan, 0, 0.5, 0).ok
    assert not ap.set_manual_control(0, 0, 1.5, 0).ok
    before = ap.get_param("MPC_XY_VEL_MAX")
    assert not ap.set_param("MPC_XY_VEL_MAX", float("nan")).ok
    assert not ap.set_param("MPC_XY_VEL_MAX", 1e6).ok
    assert not ap.set_param("NO_SUCH_PARAM", 1.0).ok
    assert ap.get_param("MPC_XY_VEL_MAX") == before
    items = [MissionItem(MissionCommand.WAYPOINT, np.array([np.nan, 0.0, -10.0]))]
    assert not ap.set_mission(items).ok
    assert ap.mode == FlightMode.OFFBOARD

    def stream(a, s):
        a.set_offboard_setpoint(Setpoint(pos_ned=target))
        a.set_offboard_setpoint(Setpoint(pos_ned=np.array([np.nan, 1, 2])))

    fly(ap, 8.0, stream)
    assert np.linalg.norm(ap.state.pos_ned - target) < 0.2


def test_manual_modes_follow_sticks():
    ap = MultirotorAutopilot()
    assert not ap.set_mode(FlightMode.POSCTL).ok  # no sticks yet
    ap.set_manual_control(0, 0, 0.5, 0)
    assert ap.set_mode(FlightMode.POSCTL).ok and ap.arm().ok
    fly(ap, 3.0, lambda a, s: a.set_manual_control(0, 0, 1.0, 0))  # full up: climb at max
    assert ap.state.vel_ned[2] == pytest.approx(-3.0, abs=0.1)
    fly(ap, 3.0, lambda a, s: a.set_manual_control(0, 0, 0.5, 0))  # centred: hold height
    z = ap.state.pos_ned[2]
    fly(ap, 5.0, lambda a, s: a.set_manual_control(0.5, 0, 0.5, 0))  # half forward: 5 m/s N
    assert ap.state.vel_ned[0] == pytest.approx(5.0, abs=0.3)
    assert abs(ap.state.pos_ned[2] - z) < 0.5
    fly(ap, 4.0, lambda a, s: a.set_manual_control(0, 0, 0.5, 0))
    assert np.linalg.norm(ap.state.vel_ned) < 0.1
    assert ap.set_mode(FlightMode.STABILIZED).ok
    fly(ap, 1.0, lambda a, s: a.set_manual_control(0, 1.0, 0.5, 0))  # right roll stick
    roll = ap.state.euler[0]
    assert roll == pytest.approx(math.radians(35.0), abs=0.02)
    assert ap.state.vel_ned[1] > 1.0  # moving east
    fly(ap, 1.0)  # sticks lost → hold
    assert ap.mode == FlightMode.HOLD


def test_same_seed_same_flight_bit_for_bit():
    def run(seed=3):
        wind = WindModel(mean_ned=(3.0, 1.0, 0.0), gust_std=1.5, gust_tau=1.0, seed=seed)
        ap = MultirotorAutopilot(seed=seed, clock=SimClock(), wind=wind)
        ap.arm()
        ap.takeoff(8.0)
        _, p1 = fly(ap, 8.0)
        ap.reposition(np.array([10.0, -5.0, -12.0]), yaw=1.0)
        _, p2 = fly(ap, 8.0)
        return np.concatenate([p1, p2]), ap.state

    (a, sa), (b, sb) = run(), run()
    assert a.tobytes() == b.tobytes()
    assert sa.quat.tobytes() == sb.quat.tobytes() and sa.t == sb.t
    c, _ = run(seed=4)  # other gusts: another flight
    assert c.tobytes() != a.tobytes()


def test_yaw_setpoint_tracked():
    ap = airborne(10.0)
    assert ap.reposition(ap.state.pos_ned, yaw=2.5).ok
    fly(ap, 5.0)
    assert ap.state.euler[2] == pytest.approx(2.5, abs=0.02)
    assert np.linalg.norm(ap.state.pos_ned - [0, 0, -10]) < 0.3


def test_battery_drains_at_hover_power():
    ap = airborne(10.0, settle=10.0)
    b0, t0, e0 = ap.battery_remaining, ap.clock.t, ap._aux[6]
    fly(ap, 60.0)
    v = ap.vehicle
    w_h = v.hover_command * v.omega_max
    p_shaft = 4 * v.k_torque * w_h**3  # Q ω per rotor at hover
    p_el = p_shaft / v.efficiency + v.avionics_power
    expected = p_el * (ap.clock.t - t0) / (v.battery_capacity_wh * 3600)
    assert b0 - ap.battery_remaining == pytest.approx(expected, rel=0.02)
    assert ap._aux[6] > e0
    assert v.voltage_empty < ap.battery_voltage < v.voltage_full


def test_control_rates_other_than_250hz_fly_too():
    for dt in (0.002, 0.01):
        ap = MultirotorAutopilot(control_dt=dt)
        ap.arm()
        ap.takeoff(5.0)
        fly(ap, 8.0)
        assert abs(ap.state.pos_ned[2] + 5.0) < 0.25
    with pytest.raises(ValueError):
        MultirotorAutopilot(control_dt=0.0025)


def test_armed_idle_on_ground_does_not_drift_for_60s():
    ap = MultirotorAutopilot(start_yaw=0.7)
    assert ap.set_param("COM_DISARM_PRFLT", -1.0).ok
    assert ap.arm().ok
    _, p = fly(ap, 60.0)
    assert ap.armed and ap.state.on_ground and ap.landed_state == LandedState.ON_GROUND
    assert np.all(p == 0.0)
    assert ap.state.euler[2] == pytest.approx(0.7, abs=1e-12)
    assert np.all(ap.motor_commands == pytest.approx(ap.get_param("MOT_SPIN_ARM")))


def test_altctl_holds_height_when_stick_centred():
    ap = MultirotorAutopilot()
    ap.set_manual_control(0, 0, 0.5, 0)
    assert ap.set_mode(FlightMode.ALTCTL).ok and ap.arm().ok
    fly(ap, 4.0, lambda a, s: a.set_manual_control(0, 0, 0.75, 0))  # half up
    assert ap.state.vel_ned[2] == pytest.approx(-1.5, abs=0.1)
    fly(ap, 3.0, lambda a, s: a.set_manual_control(0, 0, 0.5, 0))
    z = ap.state.pos_ned[2]
    _, p = fly(ap, 5.0, lambda a, s: a.set_manual_control(0.3, 0, 0.5, 0))  # pitch forward
    assert np.abs(p[:, 2] - z).max() < 0.3 and ap.state.vel_ned[0] > 2.0
    assert ap.state.euler[1] == pytest.approx(-0.3 * math.radians(35.0), abs=0.02)


def test_mission_current_loiter_and_rtl_items():
    ap = airborne(10.0)
    items = [
        MissionItem(MissionCommand.WAYPOINT, np.array([50.0, 0.0, -10.0])),
        MissionItem(MissionCommand.LOITER_TIME, np.array([10.0, 10.0, -12.0]), hold_s=3.0),
        MissionItem(MissionCommand.RETURN_TO_LAUNCH, np.zeros(3)),
    ]
    assert ap.set_mission(items).ok
    assert not ap.set_mission_current(3).ok and not ap.set_mission_current(-1).ok
    assert ap.set_mission_current(1).ok  # skip the first waypoint
    assert ap.set_mode(FlightMode.MISSION).ok
    times = {}

    def watch(a, s):
        for seq in a.mission_progress.reached:
            times[seq] = a.clock.t
        a.mission_progress.reached.clear()

    _, p = fly(ap, 80.0, watch)
    assert sorted(times) == [1, 2] and times[2] - times[1] >= 3.0  # loitered 3 s
    assert p[:, 0].max() < 15.0  # never flew to item 0
    assert ap.mode == FlightMode.RTL and ap.state.on_ground and not ap.armed
    assert math.hypot(*ap.state.pos_ned[:2]) < 1.0


def test_battery_critical_returns_and_emergency_lands():
    ap = MultirotorAutopilot(battery_start=0.09)  # 9 %: about 2 min of hover left
    assert ap.arm().ok and ap.takeoff(10.0).ok
    fly(ap, 8.0)
    assert ap.reposition(np.array([60.0, 0.0, -10.0])).ok
    modes = []
    _, p = fly(ap, 200.0, lambda a, s: modes.append(a.mode))
    events = " ".join(ap.drain_status())
    assert "critical -> return" in events and "emergency -> land" in events
    i_rtl, i_land = modes.index(FlightMode.RTL), modes.index(FlightMode.LAND)
    assert i_rtl < i_land
    assert ap.state.on_ground and not ap.armed
    assert ap.battery_remaining < 0.05


def test_hold_entered_at_speed_brakes_and_holds_where_it_stopped():
    ap = airborne(10.0)
    sp = Setpoint(vel_ned=np.array([8.0, 0.0, 0.0]))
    ap.set_offboard_setpoint(sp)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    fly(ap, 5.0, lambda a, s: a.set_offboard_setpoint(sp))
    assert ap.state.vel_ned[0] == pytest.approx(8.0, abs=0.2)
    x_loss = ap.state.pos_ned[0]
    _, p = fly(ap, 15.0)  # stream stops → HOLD
    assert ap.mode == FlightMode.HOLD
    x = p[:, 0]
    stop = x.max()
    assert stop - x_loss < 8.0 * 0.5 + 8.0**2 / (2 * 5.0)  # ran on at most loss time + braking
    assert stop - x[-1] < 0.3  # did not fly back to where HOLD was entered
    assert np.linalg.norm(ap.state.vel_ned) < 0.05
    assert ap.land().ok
    _, p = fly(ap, 20.0)
    assert np.abs(p[:, 0] - p[-1, 0]).max() < 0.3 and ap.state.on_ground


def test_implements_the_autopilot_protocol():
    import inspect

    from skyherd.flight.autopilot_api import Autopilot

    ap = MultirotorAutopilot()
    members = [n for n in dir(Autopilot) if not n.startswith("_")]
    members += list(Autopilot.__annotations__)
    for name in members:
        assert hasattr(ap, name), name
        proto = getattr(Autopilot, name, None)
        if inspect.isfunction(proto):
            want = list(inspect.signature(proto).parameters)[1:]
            got = list(inspect.signature(getattr(ap, name)).parameters)
            assert got == want, (name, got, want)
    assert ap.airframe == "quadrotor" and ap.control_dt == 0.004
    t0 = ap.clock.time_us
    ap.step()
    assert ap.clock.time_us - t0 == 4000  # step advances the shared clock by control_dt


def test_mission_takeoff_item_without_height_uses_mis_takeoff_alt():
    ap = MultirotorAutopilot()
    items = [
        MissionItem(MissionCommand.TAKEOFF, np.zeros(3)),
        MissionItem(MissionCommand.LOITER_UNLIM, np.array([5.0, 0.0, -4.0])),
    ]
    assert ap.set_mission(items).ok and ap.set_mode(FlightMode.MISSION).ok and ap.arm().ok
    _, p = fly(ap, 20.0)
    assert ap.mission_progress.reached == [0, 1] and not ap.mission_progress.finished
    i = int(np.argmax(p[:, 2] <= -1.6))  # within NAV_MC_ALT_RAD (0.8 m) of 2.5 m ...
    assert i > 0 and abs(p[i, 0]) < 0.05  # ... straight up, before heading for item 1
    assert np.linalg.norm(ap.state.pos_ned - [5.0, 0.0, -4.0]) < 0.2  # loiters there
