"""Random request sequences (NaN, inf, huge, wrong types) never crash the autopilot."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skyherd.flight.autopilot_api import FlightMode, MissionCommand, MissionItem, Setpoint
from skyherd.flight.multirotor import MultirotorAutopilot

num = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True, width=64),
    st.sampled_from([0.0, 1.0, -1.0, 5.0, -10.0, 0.5, 1e300]),
)
vec = st.one_of(st.none(), st.lists(num, min_size=3, max_size=3).map(np.array))
calls = st.one_of(
    st.tuples(st.just("arm"), st.booleans()),
    st.tuples(st.just("disarm"), st.booleans()),
    st.tuples(st.just("set_mode"), st.sampled_from(list(FlightMode) + ["bogus", None])),
    st.tuples(st.just("takeoff"), st.one_of(st.none(), num, st.just("x"))),
    st.tuples(st.just("land")),
    st.tuples(st.just("return_to_launch")),
    st.tuples(st.just("reposition"), vec, st.one_of(st.none(), num)),
    st.tuples(st.just("offboard"), vec, vec, st.one_of(st.none(), num)),
    st.tuples(st.just("manual"), num, num, num, num),
    st.tuples(
        st.just("mission"),
        st.lists(st.tuples(st.sampled_from(list(MissionCommand)), vec, num), max_size=4),
    ),
    st.tuples(st.just("mission_current"), st.integers(-3, 6)),
    st.tuples(
        st.just("param"),
        st.sampled_from(["MPC_XY_VEL_MAX", "MPC_Z_P", "NOPE", "COM_OF_LOSS_T"]),
        num,
    ),
    st.tuples(st.just("steps"), st.integers(1, 300)),
)


def apply(ap, call):
    name, *a = call
    if name == "arm":
        return ap.arm(force=a[0])
    if name == "disarm":
        return ap.disarm(force=a[0])
    if name == "set_mode":
        return ap.set_mode(a[0])
    if name == "takeoff":
        return ap.takeoff(a[0])
    if name == "land":
        return ap.land()
    if name == "return_to_launch":
        return ap.return_to_launch()
    if name == "reposition":
        return ap.reposition(a[0] if a[0] is not None else np.array([0.0, 0, -5]), a[1])
    if name == "offboard":
        return ap.set_offboard_setpoint(Setpoint(pos_ned=a[0], vel_ned=a[1], yaw=a[2]))
    if name == "manual":
        return ap.set_manual_control(*a)
    if name == "mission":
        items = [MissionItem(c, p if p is not None else np.zeros(3), hold_s=h) for c, p, h in a[0]]
        return ap.set_mission(items)
    if name == "mission_current":
        return ap.set_mission_current(a[0])
    if name == "param":
        return ap.set_param(*a)
    for _ in range(a[0]):
        ap.step()
    return None


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(calls, min_size=1, max_size=25))
def test_random_requests_never_crash_and_state_stays_physical(seq):
    ap = MultirotorAutopilot()
    for call in seq:
        r = apply(ap, call)
        if r is not None:
            assert isinstance(r.ok, bool) and (r.ok or r.reason)
        s = ap.state
        for arr in (s.pos_ned, s.vel_ned, s.quat, s.omega_frd, s.accel_frd):
            assert np.all(np.isfinite(arr))
        assert s.pos_ned[2] <= 0.0
        assert abs(np.linalg.norm(s.quat) - 1.0) < 1e-9
        assert 0.0 <= ap.battery_remaining <= 1.0
        assert isinstance(ap.mode, FlightMode)
