"""The fixed-wing's own fence (targets refused, GF_ACTION on breach) and faults on JSBSim
(wind triangle, GPS glitch in the estimate it flies on). Simulation time only."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, MissionCommand, MissionItem, Setpoint
from skyherd.flight.faults import FaultEvent, FaultPlan, parse_fault_args
from skyherd.flight.fixedwing.autopilot import FixedWingAutopilot


def circle(r: float, n: float = 0.0, e: float = 0.0, inclusion: bool = True):
    return SimpleNamespace(kind="circle", inclusion=inclusion, center_ne=np.array([n, e]), radius=r)


def airborne(plan: FaultPlan | None = None, alt: float = 80.0) -> FixedWingAutopilot:
    ap = FixedWingAutopilot(faults=plan)
    ap.start_in_air(alt, 24.0, 0.0)
    return ap


def fly(ap, seconds: float, sp: Setpoint | None = None):
    """(n, 3) true positions; streams sp at 10 Hz while in OFFBOARD."""
    n = round(seconds / ap.control_dt)
    out = np.empty((n, 3))
    for k in range(n):
        if sp is not None and k % 5 == 0 and ap.mode == FlightMode.OFFBOARD:
            ap.set_offboard_setpoint(sp)
        ap.step()
        out[k] = ap.true_state.pos_ned
    return out


def test_loiter_targets_must_fit_inside_the_fence():
    ap = airborne()
    ap.set_fence([circle(800.0)])
    r_loiter = ap.default_loiter_radius()
    r = ap.reposition(np.array([2000.0, 0.0, -80.0]))
    assert not r.ok and "geofence" in r.reason
    # the centre is inside, the circle is not
    r = ap.reposition(np.array([800.0 - 0.5 * r_loiter, 0.0, -80.0]))
    assert not r.ok and "loiter circle" in r.reason
    assert ap.reposition(np.array([300.0, 0.0, -80.0])).ok
    assert not ap.set_offboard_setpoint(Setpoint(pos_ned=np.array([0.0, 900.0, -80.0]))).ok
    far = [MissionItem(MissionCommand.WAYPOINT, np.array([1500.0, 0.0, -80.0]))]
    r = ap.set_mission(far)
    assert not r.ok and "item 0" in r.reason


def test_breach_loiters_toward_home_and_is_reported():
    """Flying north at 24 m/s into GF_MAX_HOR_DIST 400 m: the breach is seen within one
    20 Hz sample (1.2 m); HOLD loiters on a circle centred 1.5 r toward home, so the farthest
    point is the overshoot of the turn onto it (a half circle of radius ≥ r_min < r): < r.
    One breach only: the circle lies 0.5 r inside."""
    ap = airborne()
    assert ap.set_param("GF_MAX_HOR_DIST", 400.0).ok
    sp = Setpoint(vel_ned=np.array([24.0, 0.0, 0.0]))
    ap.set_offboard_setpoint(sp)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    p = fly(ap, 60.0, sp)
    texts = " ".join(ap.drain_status())
    assert "geofence breach" in texts and "hold (geofence)" in texts
    assert ap.mode == FlightMode.HOLD and ap.fence.breaches == 1
    assert np.hypot(p[:, 0], p[:, 1]).max() < 400.0 + ap.default_loiter_radius()
    assert np.hypot(*ap.loiter_center) < 400.0


def test_steady_wind_triangle_and_gps_glitch():
    """Wind 8 m/s from the east (blowing west) on JSBSim's atmosphere: ground velocity =
    air velocity + wind, so |v_ground − w| is the true airspeed (the wind triangle) within
    0.5 m/s. A +30 m east glitch shows in the estimate exactly, not in the truth."""
    plan = parse_fault_args(wind="8,90", faults=["gps_glitch@20:0,30,0:5"])
    ap = airborne(plan)
    assert ap.set_mode(FlightMode.HOLD).ok
    errs = []
    for _ in range(round(19.0 / ap.control_dt)):
        ap.step()
        s = ap.state
        v_air = ap.true_state.vel_ned - np.array([0.0, -8.0, 0.0])
        errs.append(abs(np.linalg.norm(v_air) - ap.airspeed))
    assert max(errs[100:]) < 0.5
    fly(ap, 1.1)
    d = ap.state.pos_ned - ap.true_state.pos_ned
    assert d == pytest.approx([0.0, 30.0, 0.0], abs=1e-9)
    fly(ap, 5.0)
    assert ap.state.pos_ned == pytest.approx(ap.true_state.pos_ned, abs=1e-9)
    assert s is not None


def test_gps_loss_beyond_timeout_loiters_and_arming_refused_without_fix():
    plan = FaultPlan(events=(FaultEvent("gps_loss", 5.0),))
    ap = airborne(plan)
    sp = Setpoint(vel_ned=np.array([24.0, 0.0, 0.0]))
    ap.set_offboard_setpoint(sp)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    fly(ap, 11.0, sp)
    assert not ap.gps_fix and not ap.position_valid and ap.mode == FlightMode.HOLD
    assert "failsafe -> hold" in " ".join(ap.drain_status())
    ground = FixedWingAutopilot(faults=FaultPlan(events=(FaultEvent("gps_loss", 0.0),)))
    ground.step()
    r = ground.arm()
    assert not r.ok and "position" in r.reason


def corridor(west: float, east: float, n: float = 3000.0):
    """An inclusion polygon from `west` to `east` [m east of home], ±n north."""
    return SimpleNamespace(kind="polygon", inclusion=True,
                           vertices_ne=np.array([[-n, west], [n, west], [n, east], [-n, east]]))  # fmt: skip


def _hold_after_offboard_loss(ap, seconds: float = 90.0) -> np.ndarray:
    """Northbound in OFFBOARD, then the stream stops (a link cut): HOLD after COM_OF_LOSS_T."""
    sp = Setpoint(vel_ned=np.array([24.0, 0.0, 0.0]))
    ap.set_offboard_setpoint(sp)
    assert ap.set_mode(FlightMode.OFFBOARD).ok
    p = fly(ap, seconds)
    assert ap.mode == FlightMode.HOLD
    return p


def test_hold_circle_fits_the_fence_on_the_side_with_room():
    """A link cut flying north 150 m from the east edge of the fence: HOLD's default circle on
    the right (2R = 258 m to the east) would cross it; the circle on the left fits, and the
    aircraft loiters there (counter-clockwise) without ever leaving the fence."""
    ap = airborne()
    ap.set_fence([corridor(-1000.0, 150.0)])
    ap.drain_status()
    p = _hold_after_offboard_loss(ap)
    r = ap.default_loiter_radius()
    assert ap.loiter_radius == pytest.approx(r)
    assert ap.loiter_center[1] == pytest.approx(-r, abs=5.0)  # west of the track: the left
    assert p[:, 1].max() < 150.0 and ap.fence.breaches == 0
    assert "left of the course fits the geofence" in " ".join(ap.drain_status())


def test_sabotaged_loiter_radius_shrinks_to_fit_the_fence():
    """NAV_LOITER_RAD = 400 m (the campaign's sabotage) in a corridor 400 m wide: neither side
    fits at 400 m, the circle shrinks (15 % a try) until it does, never below the tightest turn
    the bank limit flies, and the aircraft stays inside."""
    ap = airborne()
    assert ap.set_param("NAV_LOITER_RAD", 400.0).ok
    ap.set_fence([corridor(-200.0, 200.0)])
    p = _hold_after_offboard_loss(ap)
    assert ap._min_loiter_radius() <= ap.loiter_radius < 200.0 / 1.1
    assert np.abs(p[:, 1]).max() < 200.0 and ap.fence.breaches == 0


def test_hold_without_a_fence_is_the_default_circle():
    ap = airborne()
    _hold_after_offboard_loss(ap, 5.0)
    r = ap.default_loiter_radius()
    assert ap.loiter_radius == pytest.approx(r) and ap.loiter_center[1] > 0.9 * r  # the right


def test_fixedwing_battery_failsafe_stands_in_a_drill():
    """The fixed-wing's battery (fuel) failsafe, PX4 COM_LOW_BAT_ACT 3 as the multirotor's:
    below BAT_CRIT_THR it returns, below BAT_EMERGEN_THR it lands; the net yields to it and
    never undoes it (safety.campaign battery drills, in-process; seed 7, drills 0 and 1)."""
    from skyherd.safety.campaign import drill_rng, make_drill, make_vehicle
    from skyherd.safety.config import default_envelope_path, fill_dataclass, load_envelope
    from skyherd.safety.drills import DrillParams, run_drill
    from skyherd.safety.supervisor import SupervisorParams

    spec, table = load_envelope(default_envelope_path("fixedwing"))
    sp = fill_dataclass(SupervisorParams, table, "supervisor")
    p = DrillParams()
    for index, want, said in ((0, "RTL", "critical -> return"), (1, "LAND", "emergency -> land")):
        d = make_drill("battery", index, drill_rng(7, "fixedwing", index), spec, p)
        ap = make_vehicle(d, 7)
        r = run_drill(d.script, ap, d.spec, sp, p)
        assert r.passed, r.why
        assert r.yielded == want and r.overridden == 0
        assert r.min_clearance_m > 10.0
        assert any(said in line for line in ap.drain_status())
