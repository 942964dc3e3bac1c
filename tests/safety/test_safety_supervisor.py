"""Scripted timelines of the Simplex supervisor (PX4 commander style: advance time, assert)."""

import json
import math

import numpy as np
import pytest

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.frames import euler_to_quat
from skyherd.flight.geo import GRAVITY
from skyherd.flight.state import VehicleState
from skyherd.runio.runfolder import JsonlWriter
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.envelope import Dynamics
from skyherd.safety.fallback import LoiterFallback, PidGains, RecoveryPID, recovery_target
from skyherd.safety.supervisor import Health, Mode, Severity, Supervisor, SupervisorParams

SPEC, _ = load_envelope(default_envelope_path("quadrotor"))
DT = 0.02


def st(t, p=(0.0, 0.0, -20.0), v=(0.0, 0.0, 0.0), roll=0.0):
    return VehicleState(
        t,
        np.array(p, float),
        np.array(v, float),
        euler_to_quat(roll, 0, 0),
        np.zeros(3),
        np.array([0, 0, -GRAVITY]),
        False,
    )


def sp(u):
    return Setpoint(vel_ned=np.array(u, float))


class Sink:
    def __init__(self):
        self.records = []

    def write(self, r):
        self.records.append(r)


def run(sup, t0, t1, state_fn, prop_fn, health_fn=lambda t: Health()):
    """Advance from t0 to t1 in DT steps; return the last decision."""
    d = None
    for k in range(round((t1 - t0) / DT)):
        t = t0 + k * DT
        d = sup.update(t, state_fn(t), prop_fn(t), health_fn(t))
    return d


def test_severity_is_ordered():
    assert Severity.NONE < Severity.NEAR < Severity.PROJECTED < Severity.FALLBACK
    assert max(Severity.NEAR, Severity.FALLBACK) is Severity.FALLBACK


def test_fence_breach_fallback_pid_and_hysteresis_timeline(tmp_path):
    w = JsonlWriter(tmp_path / "events.jsonl")
    sup = Supervisor(SPEC.envelope(), SupervisorParams(hysteresis_s=2.0, hold_min_s=1.0), w)
    # 0-1 s: safe hover commands pass through unchanged
    d = run(sup, 0.0, 1.0, lambda t: st(t), lambda t: sp([0.5, 0, 0]))
    assert (
        d.mode is Mode.AI
        and d.autopilot_mode is FlightMode.OFFBOARD
        and np.allclose(d.command.vel_ned, [0.5, 0, 0])
    )
    # t = 1: at 74 m north doing 3 m/s toward the edge at 80 m: predicted stop beyond 78 m
    d = sup.update(1.0, st(1.0, (74, 0, -20), (3, 0, 0)), sp([3, 0, 0]))
    assert (
        d.mode is Mode.FALLBACK
        and d.reason == "field edge 2"
        and d.autopilot_mode is FlightMode.HOLD
    )
    assert d.severity is Severity.FALLBACK and d.ai_rejected
    assert np.allclose(d.command.vel_ned, 0) and d.command.pos_ned is None  # brake
    # 1-2.5 s: still moving faster than settle speed → stays in FALLBACK past hold_min
    d = run(sup, 1.02, 2.5, lambda t: st(t, (75, 0, -20), (1.0, 0, 0)), lambda t: sp([0, 0, 0]))
    assert d.mode is Mode.FALLBACK
    # stopped: the hover fallback holds where it stopped, then PID takes over
    d = sup.update(2.5, st(2.5, (75.5, 0, -20), (0.1, 0, 0)), sp([0, 0, 0]))
    assert d.mode is Mode.FALLBACK and np.allclose(d.command.pos_ned, [75.5, 0, -20])
    d = sup.update(2.52, st(2.52, (75.5, 0, -20)), sp([0, 0, 0]))
    assert d.mode is Mode.PID and d.autopilot_mode is FlightMode.OFFBOARD
    assert sup.pid.target[0] == pytest.approx(80 - 6.0, abs=1e-3)  # recover_margin_m inside
    assert d.command.vel_ned[0] < 0  # heads back inside
    # at the target: AI proposals clean for 1.9 s → still PID; an unsafe one resets the window
    at = lambda t: st(t, (74, 0, -20))  # noqa: E731
    d = run(sup, 2.54, 4.4, at, lambda t: sp([0, 0, 0]))
    assert d.mode is Mode.PID
    d = sup.update(4.4, at(4.4), sp([0, 6, 0]))  # too aggressive (tilt)
    assert d.mode is Mode.PID and d.reason.startswith("tilt 20 deg")
    d = run(sup, 4.42, 6.42, at, lambda t: sp([0, 0, 0]))  # window restarts at 4.42 s
    assert d.mode is Mode.PID  # at 6.40 s: 1.98 s clean
    d = sup.update(6.42, at(6.42), sp([0, 0, 0]))
    assert d.mode is Mode.AI and np.allclose(d.command.vel_ned, 0)  # 2.00 s clean
    w.close()
    ev = [json.loads(line) for line in (tmp_path / "events.jsonl").read_text().splitlines()]
    assert [(e["from"], e["to"]) for e in ev] == [
        ("ai", "fallback"),
        ("fallback", "pid"),
        ("pid", "ai"),
    ]
    assert (
        ev[0]["reason"] == "field edge 2"
        and ev[0]["t"] == 1.0
        and ev[0]["action"] == [3.0, 0.0, 0.0]
    )
    assert (
        ev[0]["state"]["pos_ned"] == [74.0, 0.0, -20.0]
        and ev[0]["envelope_version"] == SPEC.version
    )
    assert ev[2]["t"] == pytest.approx(6.42) and sup.stats.switches == 3


@pytest.mark.parametrize(
    "prop, health, reason",
    [
        (sp([math.nan, 0, 0]), Health(), "non-finite action"),
        (sp([math.inf, 0, 0]), Health(), "non-finite action"),
        (sp([1e9, 0, 0]), Health(), "action out of range"),
        (Setpoint(), Health(), "malformed action"),
        (sp([0, 0, 0]), Health(camera_t=0.0), "camera lost"),
        (sp([0, 0, 0]), Health(link_t=0.0), "MAVLink link lost"),
    ],
)
def test_bad_inputs_are_violations(prop, health, reason):
    sup = Supervisor(SPEC.envelope())
    run(sup, 0.0, 0.5, lambda t: st(t), lambda t: sp([0, 0, 0]))  # healthy until 0.5 s
    d = sup.update(2.0, st(2.0), prop, health)
    assert (
        d.mode is Mode.FALLBACK
        and d.reason.startswith(reason)
        and d.autopilot_mode is FlightMode.HOLD
    )


def test_deadline_counts_from_the_last_action():
    sup = Supervisor(SPEC.envelope(), SupervisorParams(deadline_s=0.3))
    sup.update(0.0, st(0.0), sp([0, 0, 0]))
    d = run(sup, 0.02, 0.30, lambda t: st(t), lambda t: None)  # held action, within deadline
    assert d.mode is Mode.AI
    d = sup.update(0.32, st(0.32), None)
    assert d.mode is Mode.FALLBACK and d.reason == "action deadline missed (0.32 s > 0.3 s)"


def test_held_action_is_rechecked_against_the_new_state():
    sup = Supervisor(SPEC.envelope())
    assert sup.update(0.0, st(0.0, (70, 0, -20), (3, 0, 0)), sp([3, 0, 0])).mode is Mode.AI
    d = sup.update(0.1, st(0.1, (74, 0, -20), (3, 0, 0)), None)  # same command, closer
    assert d.mode is Mode.FALLBACK and d.reason == "field edge 2"


def test_measured_attitude_beyond_limit_falls_back():
    sup = Supervisor(SPEC.envelope())
    d = sup.update(0.0, st(0.0, roll=0.9), sp([0, 0, 0]))
    assert d.mode is Mode.FALLBACK and d.reason == "roll 45 deg"


def test_project_mode_keeps_the_ai_with_the_closest_safe_command():
    sup = Supervisor(SPEC.envelope(), SupervisorParams(intervention="project"))
    s = st(0.0, (72.2, 0, -20), (3, 0, 0))
    d = sup.update(0.0, s, sp([4.5, 0.5, 0]))
    assert d.mode is Mode.AI and d.severity is Severity.PROJECTED and d.reason == "field edge 2"
    u = d.command.vel_ned
    # closed form: 72.2 + k((1-a) 3 + a u_n) = 78 - 1e-4 (the solver's tightening)
    k, a = 0.02 + SPEC.stop_times()[0], 0.02 / SPEC.dynamics.tau_s
    assert u[0] == pytest.approx(((78 - 1e-4 - 72.2) / k - (1 - a) * 3) / a, abs=1e-3)
    assert u[1] == pytest.approx(0.5, abs=1e-4)  # only the offending part changes
    from skyherd.safety.monitor import make_z

    assert sup.envelope.worst(make_z(s, u)) <= 0
    d = sup.update(0.02, st(0.02), sp([math.nan, 0, 0]))  # NaN is never projected
    assert d.mode is Mode.FALLBACK
    # too close to be fixed by one command (the state alone predicts the stop beyond the edge)
    late = Supervisor(SPEC.envelope(), SupervisorParams(intervention="project"))
    d = late.update(0.0, st(0.0, (74, 0, -20), (3, 0, 0)), sp([3, 0, 0]))
    assert d.mode is Mode.FALLBACK and d.reason == "field edge 2"


def test_recovery_target_and_pid_step_response():
    geo = SPEC.geometry()
    tgt = recovery_target(geo, np.array([83.0, 10.0, -20.0]), 6.0)
    assert np.allclose(tgt, [74.0, 10.0, -20.0], atol=1e-3)
    pid = RecoveryPID(PidGains(), geo, speed_mps=3.0, margin_m=6.0)
    s = st(0.0, (83.0, 10.0, -20.0))
    pid.engage(s)
    p, v = s.pos_ned.copy(), np.zeros(3)
    tau = SPEC.dynamics.tau_s
    xs = []
    for k in range(int(20 / DT)):  # first-order velocity loop (the envelope's model)
        u = pid.command(k * DT, st(k * DT, p, v)).vel_ned
        assert np.hypot(u[0], u[1]) <= 3.0 + 1e-9
        v = v + DT / tau * (u - v)
        p = p + DT * v
        xs.append(p[0])
    xs = np.array(xs)
    assert 74.0 < xs[int(4.0 / DT)] < 76.0  # on its way after 4 s (3 m/s cap, 9 m to go)
    assert xs.min() > 74.0 - 0.1  # overshoot below 0.1 m
    assert np.allclose(p, [74.0, 10.0, -20.0], atol=0.05)


def test_loiter_fallback_radius_is_the_turn_performance():
    dyn = Dynamics(decel_h_mps2=0.0, bank_max_rad=math.radians(35))
    v = 20.0
    assert dyn.turn_radius(v) == pytest.approx(
        v * v / (GRAVITY * math.tan(math.radians(35)))
    )  # 58.25 m
    geo = SPEC.geometry()
    lf = LoiterFallback(dyn.bank_max_rad, geo, min_speed_mps=12.0)
    s = st(0.0, (0, 0, -30), (v, 0, 0))
    lf.engage(s)
    assert lf.radius == pytest.approx(58.25, abs=0.01)
    p = s.pos_ned.copy()
    dists = []
    for k in range(int(60 / DT)):  # an ideal follower of the commanded velocity
        u = lf.command(st(k * DT, p, (v, 0, 0))).vel_ned
        assert np.linalg.norm(u[:2]) == pytest.approx(v)
        p = p + DT * u
        if k * DT > 20:
            dists.append(np.linalg.norm(p[:2] - lf.center))
    assert np.mean(dists) == pytest.approx(lf.radius, rel=0.03) and np.ptp(dists) < 0.05 * lf.radius
    assert p[2] == pytest.approx(-30)


def test_fixedwing_envelope_adds_the_loiter_diameter():
    import dataclasses

    fw = dataclasses.replace(
        SPEC,
        airframe="fixedwing",
        dynamics=Dynamics(decel_h_mps2=0.0, bank_max_rad=math.radians(35), react_s=0.3),
    )
    env = fw.envelope()
    z = np.zeros(11)
    z[2] = -20
    r = env.residual(z)
    i = env.names.index("field edge 2")
    assert r[i] == pytest.approx(0 - (80 - 2 - 2 * fw.dynamics.turn_radius(8.0)))
    sup = Supervisor(env)
    assert isinstance(sup.fallback, LoiterFallback)


def test_load_net_and_apply_decision_on_the_real_autopilot():
    from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
    from skyherd.safety.net import apply_decision, load_net

    net = load_net("quadrotor", hysteresis_s=1.0)
    assert net.p.hysteresis_s == 1.0 and net.envelope.version == SPEC.version
    with pytest.raises(ValueError, match="is for quadrotor"):
        load_net("fixedwing", default_envelope_path("quadrotor"))
    ap = MultirotorAutopilot()
    ap.arm()
    ap.takeoff(10.0)
    while ap.mode is FlightMode.TAKEOFF:
        ap.step()
    d = net.update(ap.clock.t, ap.state, sp([0.5, 0, 0]))
    assert apply_decision(ap, d).ok and ap.mode is FlightMode.OFFBOARD
    d = net.update(ap.clock.t + 0.02, ap.state, sp([math.nan, 0, 0]))
    assert apply_decision(ap, d).ok and ap.mode is FlightMode.HOLD  # the autopilot's own hover
