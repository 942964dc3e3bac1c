"""Property: from any state inside the envelope, whatever the AI proposes (NaN, inf, huge
values included), the command leaving the safety net keeps the vehicle inside at the next
step of the envelope's own prediction model — and able to brake to a stop inside — or it is
the airframe fallback."""

import dataclasses
import math

import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.frames import euler_to_quat
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.envelope import Dynamics
from skyherd.safety.monitor import Monitor, make_z
from skyherd.safety.supervisor import Mode, Supervisor, SupervisorParams

SPEC, _ = load_envelope(default_envelope_path("quadrotor"))
ENV, GEO = SPEC.envelope(), SPEC.geometry()
LIM, DYN = SPEC.limits, SPEC.dynamics
SUPS = {m: Supervisor(ENV, SupervisorParams(intervention=m)) for m in ("switch", "project")}

finite = st.floats(-12.0, 12.0)
wild = st.one_of(
    finite,
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([math.nan, math.inf, -math.inf, 1e308, -1e12, 0.0]),
)


@st.composite
def states(draw):
    p = np.array(
        [
            draw(st.floats(-80, 80)),
            draw(st.floats(-80, 80)),
            -draw(st.floats(LIM.floor_m, LIM.ceiling_m)),
        ]
    )
    assume(GEO.distance_outside(p) <= 0.0)
    sp, hd = draw(st.floats(0, LIM.speed_h_mps)), draw(st.floats(-math.pi, math.pi))
    v = np.array(
        [sp * math.cos(hd), sp * math.sin(hd), draw(st.floats(-LIM.climb_mps, LIM.descent_mps))]
    )
    lim = LIM.attitude_max_rad
    q = euler_to_quat(
        draw(st.floats(-lim, lim)), draw(st.floats(-lim, lim)), draw(st.floats(-math.pi, math.pi))
    )
    return VehicleState(0.0, p, v, q, np.zeros(3), np.array([0, 0, -GRAVITY]), False)


def fresh(sup):
    sup.mode, sup.last_action_t, sup.last_u, sup.last_t = Mode.AI, None, None, None
    return sup


def stop_point(p1, v1):
    """Where braking at the envelope's decelerations from (p1, v1) ends (exact curves)."""
    sh = float(np.hypot(v1[0], v1[1]))
    dh = sh * sh / (2 * DYN.decel_h_mps2) + sh * DYN.react_s
    sv = abs(float(v1[2]))
    dv = sv * sv / (2 * DYN.decel_v_mps2) + sv * DYN.react_s
    out = p1.copy()
    if sh > 0:
        out[:2] += v1[:2] / sh * dh
    out[2] += math.copysign(dv, v1[2]) if sv > 0 else 0.0
    return out


@settings(
    max_examples=400,
    deadline=None,
    suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow],
)
@given(s=states(), u=st.tuples(wild, wild, wild), mode=st.sampled_from(["switch", "project"]))
def test_command_keeps_vehicle_inside_or_is_fallback(s, u, mode):
    sup = fresh(SUPS[mode])
    d = sup.update(0.0, s, Setpoint(vel_ned=np.array(u, dtype=float)))
    if d.mode is Mode.FALLBACK:
        assert d.autopilot_mode is FlightMode.HOLD
        assert np.allclose(d.command.vel_ned, 0.0)  # hover: brake to zero velocity
        return
    assert d.mode is Mode.AI and d.autopilot_mode is FlightMode.OFFBOARD
    cmd = np.asarray(d.command.vel_ned)
    assert np.all(np.isfinite(cmd))
    z = make_z(s, cmd)
    assert ENV.worst(z) <= 0.0
    p1, v1 = Monitor(ENV).predict(z)
    assert GEO.distance_outside(p1) <= 1e-9  # inside at the next step
    assert GEO.distance_outside(stop_point(p1, v1)) <= 1e-9  # and can brake to a stop inside
    if mode == "switch":
        assert np.array_equal(cmd, np.asarray(u, float))  # passed through untouched


FW = dataclasses.replace(
    SPEC,
    airframe="fixedwing",
    dynamics=Dynamics(
        dt_s=0.02,
        tau_s=0.5,
        decel_h_mps2=0.0,
        decel_v_mps2=1.5,
        react_s=0.3,
        bank_max_rad=math.radians(35),
    ),
)
FW_SUP = Supervisor(FW.envelope())


@settings(
    max_examples=150,
    deadline=None,
    suppress_health_check=[HealthCheck.filter_too_much, HealthCheck.too_slow],
)
@given(s=states(), u=st.tuples(wild, wild, wild))
def test_fixedwing_command_inside_or_loiter(s, u):
    sup = fresh(FW_SUP)
    d = sup.update(0.0, s, Setpoint(vel_ned=np.array(u, dtype=float)))
    if d.mode is Mode.FALLBACK:
        assert d.autopilot_mode is FlightMode.HOLD  # loiter, the fixed-wing's HOLD
        lf = sup.fallback
        assert lf.radius == max(np.hypot(*s.vel_ned[:2]), lf.min_speed) ** 2 / (
            GRAVITY * math.tan(math.radians(35))
        )
        return
    z = make_z(s, np.asarray(d.command.vel_ned))
    assert FW.envelope().worst(z) <= 0.0
    p1, _ = Monitor(FW.envelope()).predict(z)
    assert FW.geometry().distance_outside(p1) <= 1e-9


def test_the_property_exercises_both_branches():
    """The generators reach both outcomes often (the property is not vacuous)."""
    rng = np.random.default_rng(0)
    outcomes = {Mode.AI: 0, Mode.FALLBACK: 0}
    for _ in range(300):
        p = np.array([*rng.uniform(-80, 80, 2), -rng.uniform(5, 60)])
        if GEO.distance_outside(p) > 0:
            continue
        v = np.append(rng.uniform(-5, 5, 2), rng.uniform(-2, 2))
        s = VehicleState(0.0, p, v, euler_to_quat(0, 0, 0), np.zeros(3), np.zeros(3), False)
        d = fresh(SUPS["switch"]).update(0.0, s, Setpoint(vel_ned=v + rng.normal(0, 1.0, 3)))
        outcomes[d.mode] += 1
    assert outcomes[Mode.AI] > 50 and outcomes[Mode.FALLBACK] > 50
