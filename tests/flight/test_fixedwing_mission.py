"""A whole flight in-process: runway take-off, 4-waypoint mission, hold, RTL, landing."""

import math

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, LandedState, MissionCommand, MissionItem
from skyherd.flight.fixedwing.autopilot import FixedWingAutopilot, Phase

WPS = [(500.0, 0.0, -50.0), (500.0, 500.0, -60.0), (0.0, 500.0, -60.0), (-200.0, 250.0, -50.0)]


class Recorder:
    def __init__(self, ap):
        self.ap = ap
        self.rows = []
        self.landed_states = []
        self.touchdown = None

    def __call__(self, s):
        ap = self.ap
        self.rows.append((s.t, *s.pos_ned, *s.euler, -s.vel_ned[2], ap.airspeed))
        ls = ap.landed_state
        if not self.landed_states or self.landed_states[-1] != ls:
            self.landed_states.append(ls)
        if self.touchdown is None and ap.phase == Phase.ROLLOUT:
            self.touchdown = (s.pos_ned.copy(), float(s.vel_ned[2]), ap.airspeed)

    def arr(self):
        return np.array(self.rows)


def run_until(ap, rec, cond, limit_s):
    for _ in range(round(limit_s / ap.control_dt)):
        ap.step()
        s = ap.state
        rec(s)
        if cond(s):
            return s
    raise AssertionError(f"condition not met within {limit_s} s (phase {ap.phase}, mode {ap.mode})")


@pytest.mark.slow
def test_takeoff_mission_hold_rtl_land():
    ap = FixedWingAutopilot()
    rec = Recorder(ap)
    items = [MissionItem(MissionCommand.TAKEOFF, np.array([0.0, 0.0, -40.0]))]
    items += [MissionItem(MissionCommand.WAYPOINT, np.array(p)) for p in WPS]
    assert ap.set_mission(items).ok
    assert ap.arm().ok and ap.set_mode(FlightMode.MISSION).ok

    # Runway take-off: lift-off within 350 m, on the centre line.
    run_until(ap, rec, lambda s: ap.phase == Phase.TAKEOFF_CLIMB, 40.0)
    a = rec.arr()
    assert a[-1, 1] < 350.0 and np.max(np.abs(a[:, 2])) < 3.0

    # Mission: every item reached, in order; each waypoint passed close by.
    run_until(ap, rec, lambda s: ap.mission_progress.finished, 300.0)
    assert ap.mission_progress.reached == [0, 1, 2, 3, 4]
    a = rec.arr()
    for wp in WPS:
        assert np.min(np.hypot(a[:, 1] - wp[0], a[:, 2] - wp[1])) < 45.0, wp
    assert ap.mode == FlightMode.MISSION and ap.phase == Phase.LOITER  # loiters at the end

    # Hold: loiter at the present altitude.
    assert ap.set_mode(FlightMode.HOLD).ok
    h0 = ap.state.altitude
    n0 = len(rec.rows)
    run_until(ap, rec, lambda s: False if s.t < rec.rows[n0][0] + 60.0 else True, 61.0)
    a = rec.arr()[n0:]
    assert np.max(np.abs(-a[:, 3] - h0)) < 5.0

    # RTL: back over home at RTL_RETURN_ALT, circling it.
    assert ap.return_to_launch().ok
    run_until(ap, rec, lambda s: ap.phase == Phase.LOITER, 120.0)
    n1 = len(rec.rows)
    run_until(ap, rec, lambda s: s.t > rec.rows[n1][0] + 60.0, 61.0)
    a = rec.arr()[n1 + 1500 :]  # after settling on the circle
    r = ap.loiter_radius
    assert np.allclose(ap.loiter_center, 0.0)
    assert np.max(np.abs(np.hypot(a[:, 1], a[:, 2]) - r)) < 0.1 * r
    assert np.max(np.abs(-a[:, 3] - ap.p("RTL_RETURN_ALT"))) < 5.0
    assert ap.mode == FlightMode.RTL

    # Land on home's runway (heading north): circle down, final, flare, roll-out, disarm.
    assert ap.land().ok and ap.landed_state == LandedState.LANDING
    run_until(ap, rec, lambda s: not ap.armed, 400.0)
    pos, vd, vair = rec.touchdown
    assert -50.0 < pos[0] < 100.0 and abs(pos[1]) < 10.0  # on the runway, near the aim point
    assert vd < 1.5 and vair < 22.0  # gentle: sink < 1.5 m/s
    s = ap.state
    assert s.on_ground and np.linalg.norm(s.vel_ned) < 0.3 and abs(s.pos_ned[1]) < 10.0
    a = rec.arr()
    assert np.max(np.abs(a[:, 4])) < math.radians(ap.p("FW_R_LIM") + 5.0)  # bank overshoot < 5 deg
    assert np.min(a[:, 5]) > math.radians(-15)  # never nosed over
    assert rec.landed_states == [
        LandedState.TAKEOFF,
        LandedState.IN_AIR,
        LandedState.LANDING,
        LandedState.ON_GROUND,
    ]


def test_rtl_lands_by_itself_with_rtl_land_delay():
    ap = FixedWingAutopilot(params={"RTL_LAND_DELAY": 5.0})
    ap.start_in_air(60.0, 24.0, heading=math.pi / 2)
    rec = Recorder(ap)
    run_until(ap, rec, lambda s: s.t > 20.0, 21.0)
    assert ap.return_to_launch().ok
    run_until(ap, rec, lambda s: ap.mode == FlightMode.LAND, 200.0)
    run_until(ap, rec, lambda s: not ap.armed, 400.0)
    assert rec.touchdown is not None and abs(rec.touchdown[0][1]) < 10.0


def test_mission_with_loiter_time_and_land_item():
    """LOITER_TIME holds for its time on the circle; a LAND item lands along the leg's line."""
    ap = FixedWingAutopilot()
    ap.start_in_air(60.0, 24.0, heading=0.0)
    rec = Recorder(ap)
    items = [
        MissionItem(MissionCommand.LOITER_TIME, np.array([300.0, 0.0, -60.0]), hold_s=30.0),
        MissionItem(MissionCommand.WAYPOINT, np.array([900.0, 400.0, -40.0])),
        MissionItem(MissionCommand.LAND, np.array([1600.0, 400.0, 0.0])),
    ]
    assert ap.set_mission(items).ok and ap.set_mode(FlightMode.MISSION).ok
    run_until(ap, rec, lambda s: ap.mission_progress.current == 1, 200.0)
    t_loiter = rec.rows[-1][0]
    assert t_loiter > 30.0
    run_until(ap, rec, lambda s: not ap.armed, 500.0)
    assert ap.mission_progress.reached == [0, 1, 2] and ap.mission_progress.finished
    pos = rec.touchdown[0]
    assert abs(pos[1] - 400.0) < 10.0 and 1550.0 < pos[0] < 1700.0
