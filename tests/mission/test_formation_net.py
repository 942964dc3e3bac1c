"""Every formation setpoint goes through a safety net: its own supervisor per vehicle, the
fence around the plan and the other vehicles' positions as separation rows (issue 11.1), and
a vehicle behind its reference chases it inside the speed and acceleration rows."""

import numpy as np

from skyherd.flight.state import VehicleState
from skyherd.mission.formation import FormationNet
from skyherd.mission.formation_plan import FormationParams, formation_envelope
from skyherd.safety.supervisor import Mode


def state(pos, vel=(0.0, 0.0, 0.0), t=0.0):
    return VehicleState(t=t, pos_ned=np.array(pos, float), vel_ned=np.array(vel, float),
                        quat=np.array([1.0, 0, 0, 0]), omega_frd=np.zeros(3),
                        accel_frd=np.zeros(3), on_ground=False)  # fmt: skip


def nets(paths):
    spec = formation_envelope([np.array(p, float) for p in paths], FormationParams())
    return [FormationNet(k, spec) for k in range(len(paths))], spec


def test_plan_setpoint_is_certified_and_flown_as_planned():
    (n0, _), spec = nets([[(0.0, 0.0), (0.0, 2.0)], [(10.0, 0.0), (10.0, 2.0)]])
    others = [("uav1", np.array([10.0, 0.0, -9.5]), np.zeros(3))]
    st = state((0.0, 0.0, -8.0), (0.0, 1.0, 0.0))
    d = n0.certify(0.0, st, n0.rows_against(st, others), np.array([0.0, 1.0, -8.0]),
                   np.array([0.0, 1.0, 0.0]))  # fmt: skip
    assert d.mode is Mode.AI and d.verdict == "accepted"
    c = d.command
    assert np.allclose(c.pos_ned, [0, 1, -8]) and np.allclose(c.vel_ned, [0, 1, 0]) and c.yaw == 0.0
    rec = d.record(vehicle="uav0", pilot="formation")
    assert rec["proposed"]["pos_ned"] == [0.0, 1.0, -8.0] and rec["certified"]["yaw"] == 0.0
    assert spec.inclusions[0].points.min() == -10.0  # bounding box + 10 m


def test_setpoint_toward_another_vehicle_is_refused_by_the_separation_row():
    (n0, _), _ = nets([[(0.0, 0.0), (0.0, 2.0)], [(0.0, 4.0), (0.0, 6.0)]])
    # vehicle 1 hovers 3 m east of vehicle 0 at the same altitude
    others = [("uav1", np.array([0.0, 3.0, -8.0]), np.zeros(3))]
    st = state((0.0, 0.0, -8.0), (0.0, 1.5, 0.0))
    d = n0.certify(0.0, st, n0.rows_against(st, others), np.array([0.0, 3.0, -8.0]),
                   np.array([0.0, 2.0, 0.0]))  # fmt: skip
    assert d.mode is Mode.FALLBACK and d.reason == "separation 1 m from uav1"
    assert d.command.pos_ned is None and np.allclose(d.command.vel_ned, 0)  # brake


def test_setpoint_outside_the_formation_fence_is_refused():
    (n0,), _ = nets([[(0.0, 0.0), (0.0, 2.0)]])
    st = state((0.0, 8.0, -8.0), (0.0, 2.0, 0.0))  # 4 m from the fence
    d = n0.certify(0.0, st, n0.rows_against(st, []), np.array([0.0, 9.0, -8.0]),
                   np.array([0.0, 2.0, 0.0]))  # fmt: skip
    assert d.mode is Mode.FALLBACK and "formation field edge" in d.reason


def test_a_vehicle_far_behind_chases_inside_the_acceleration_row_and_catches_up():
    """At rest 40 m behind a reference moving at 2 m/s: the old 3 m leash + feed-forward asked
    for a 4.85 m/s step (9.7 m/s² through τ = 0.5 s) and the net refused it for ever. The chase
    keeps |u − v| inside the accel row, so every proposal is accepted and the speed builds up."""
    (n0,), spec = nets([[(0.0, 0.0), (0.0, 60.0)]])
    p, v = np.array([0.0, 0.0, -8.0]), np.zeros(3)
    tau, dt = spec.dynamics.tau_s, 0.1
    speeds = []
    for i in range(200):  # 20 s: a first-order velocity response to what the net certified
        t = i * dt
        ref = np.array([0.0, min(40.0 + 2.0 * t, 60.0), -8.0])
        st = state(p, v, t)
        d = n0.certify(t, st, n0.rows_against(st, []), ref, np.array([0.0, 2.0, 0.0]))
        assert d.mode is Mode.AI and d.verdict == "accepted", (t, d.reason)
        c = d.command
        u = c.vel_ned + 0.95 * (c.pos_ned - p)  # what the autopilot flies (MPC_XY_P 0.95)
        assert np.hypot(*(u[:2] - v[:2])) / tau <= spec.limits.accel_h_mps2
        v = v + (u - v) * (dt / tau)
        p = p + v * dt
        speeds.append(float(np.hypot(*v[:2])))
    assert max(speeds) > 4.0 and p[1] > 45.0  # faster than the reference: it closes the gap


def test_fleet_separation_rows_are_each_vehicles_own_rows_value_for_value():
    """The formation makes all K vehicles' separation rows in one pass; each vehicle's must be
    exactly (bit for bit: decisions.jsonl is hashed) what separation_rows gives it alone,
    two vehicles on top of each other included."""
    from skyherd.safety.separation import fleet_separation_rows, separation_rows

    (n0, *_), spec = nets([[(0.0, 0.0), (0.0, 2.0)]] * 3)
    rng = np.random.default_rng(7)
    for m in (0, 1, 2, 5, 16):
        p, v = rng.normal(size=(m, 3)) * 20.0, rng.normal(size=(m, 3))
        if m >= 5:
            p[3] = p[1]  # coincident: pushed apart vertically
        names = [f"uav{j}" for j in range(m)]
        fleet = fleet_separation_rows(spec, p, v, names, n0.separation)
        assert len(fleet) == m
        for k in range(m):
            others = [(names[j], p[j], v[j]) for j in range(m) if j != k]
            A, b, why = separation_rows(spec, p[k], others, n0.separation)
            A2, b2, why2 = fleet[k]
            assert A.shape == A2.shape == (m - 1, A.shape[1]) and why == why2
            assert np.array_equal(A, A2) and np.array_equal(b, b2)
