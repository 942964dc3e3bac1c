"""The PyBullet ground world: NED in and out, agreement with the kinematic world, quietness."""

import math
import subprocess
import sys
import time

import numpy as np
import pytest

from skyherd.flight.frames import euler_to_quat
from skyherd.groundsim.behaviours import DriveParams, UGVCommand, make_behaviour, triangle_offsets
from skyherd.groundsim.kinematic import KinematicWorld
from skyherd.groundsim.ugv import GROUND_RGB, UGVModel, UGVStates, initial_states
from skyherd.groundsim.world import GroundWorld, WorldParams
from skyherd.perception.camera import CameraParams, UAVPose
from skyherd.perception.render_bullet import BulletRenderer

P = DriveParams()


class Constant:
    """Behaviour: the same (v, ω) for every UGV."""

    def __init__(self, v, w, camo=None):
        self.v, self.w, self.camo = v, w, camo

    def command(self, t, states):
        n = states.n
        camo = np.zeros(n, bool) if self.camo is None else np.asarray(self.camo)
        return UGVCommand(np.full(n, self.v), np.full(n, self.w), camo)


def test_ned_to_pybullet_and_back_through_the_world():
    st = UGVStates(np.array([[10.0, 0.0], [0.0, 5.0]]), np.array([0.0, math.pi / 2]), np.zeros(2))
    with GroundWorld(st, Constant(0.0, 0.0), P, WorldParams(n_ugv=2)) as w:
        pb = w.pb
        # NED → PyBullet: 10 m north is ENU +y; 5 m east is ENU +x; heading north is ENU yaw 90°
        p0, q0 = pb.getBasePositionAndOrientation(w.bodies[0], physicsClientId=w.cid)
        p1, q1 = pb.getBasePositionAndOrientation(w.bodies[1], physicsClientId=w.cid)
        assert p0[:2] == pytest.approx((0.0, 10.0), abs=1e-6)
        assert p1[:2] == pytest.approx((5.0, 0.0), abs=1e-6)
        assert p0[2] > 0  # above the ground: z is up in PyBullet
        assert pb.getEulerFromQuaternion(q0)[2] == pytest.approx(math.pi / 2, abs=1e-6)
        assert pb.getEulerFromQuaternion(q1)[2] == pytest.approx(0.0, abs=1e-6)
        # PyBullet → NED: move body 0 to ENU (3, -4) facing ENU yaw 0 (east)
        pb.resetBasePositionAndOrientation(
            w.bodies[0], [3.0, -4.0, 0.2], [0, 0, 0, 1], physicsClientId=w.cid
        )
        s = w.read_states()
        assert s.pos_ne[0] == pytest.approx([-4.0, 3.0], abs=1e-9)
        assert s.heading[0] == pytest.approx(math.pi / 2, abs=1e-9)


def test_driving_matches_the_kinematic_world():
    st = initial_states(triangle_offsets(3))
    rng = np.random.default_rng(0)
    with GroundWorld(st, make_behaviour("route", 3, rng), P) as w:
        k = KinematicWorld(st, make_behaviour("route", 3, np.random.default_rng(0)), P)
        t, err = 0.0, 0.0
        for _ in range(600):  # 30 s around the first corner of the route
            a, b = w.step(t, 0.05), k.step(t, 0.05)
            t += 0.05
            err = max(err, np.abs(a.pos_ne - b.pos_ne).max())
        assert err < 0.1  # [m] over 30 s and ~60 m driven
        assert np.abs(np.angle(np.exp(1j * (a.heading - b.heading)))).max() < 0.01


def test_turning_circle_in_pybullet():
    st = UGVStates(np.zeros((1, 2)), np.zeros(1), np.array([2.0]))
    with GroundWorld(st, Constant(2.0, 0.5), P, WorldParams(n_ugv=1)) as w:
        t = 0.0
        pts = []
        for _ in range(200):  # 10 s: most of a full circle (2π/0.5 = 12.6 s)
            pts.append(w.step(t, 0.05).pos_ne[0].copy())
            t += 0.05
        pts = np.array(pts)
        # clockwise circle of radius v/ω = 4 m, centre 4 m east of the start
        r = np.hypot(pts[:, 0], pts[:, 1] - 4.0)
        assert r == pytest.approx(4.0, abs=0.05)


def test_two_worlds_are_independent_clients():
    st = initial_states(np.zeros((1, 2)))
    a = GroundWorld(st, Constant(1.0, 0.0), P, WorldParams(n_ugv=1))
    b = GroundWorld(st, Constant(0.0, 0.0), P, WorldParams(n_ugv=1))
    try:
        assert a.cid != b.cid
        for i in range(20):
            a.step(i * 0.1, 0.1)
            b.step(i * 0.1, 0.1)
        assert a.states.pos_ne[0, 0] > 1.0 and abs(b.states.pos_ne[0, 0]) < 1e-6
    finally:
        a.close()
        b.close()


def test_camouflage_changes_the_rendered_marker():
    cam = CameraParams()
    st = initial_states(np.zeros((1, 2)))
    with GroundWorld(st, Constant(0.0, 0.0, [True]), P, WorldParams(n_ugv=1)) as w:
        r = BulletRenderer(w, cam)
        uav = UAVPose(np.array([0.0, 0.0, -10.0]), euler_to_quat(0, 0, 0))
        before = r.render(uav, w.states)[int(cam.cy), int(cam.cx)].astype(int)
        w.step(0.0, 0.05)
        assert w.states.camouflaged[0]
        after = r.render(uav, w.states)[int(cam.cy), int(cam.cx)].astype(int)
    assert np.ptp(before) > 100  # saturated red marker
    assert np.ptp(after) < 40 and np.abs(after - np.array(GROUND_RGB)).max() < 60


def test_world_is_quiet_on_stdout():
    code = (
        "import numpy as np\n"
        "from skyherd.groundsim.world import GroundWorld, WorldParams\n"
        "from skyherd.groundsim.behaviours import make_behaviour, triangle_offsets\n"
        "from skyherd.groundsim.ugv import initial_states\n"
        "w = GroundWorld(initial_states(triangle_offsets(3)),"
        " make_behaviour('route', 3, np.random.default_rng(0)))\n"
        "[w.step(i * 0.05, 0.05) for i in range(20)]\n"
        "w.close()\n"
        "print('done')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout == "done\n"  # no PyBullet banner, no warnings


def test_husky_option_drives_forward_with_its_wheels():
    st = initial_states(np.zeros((1, 2)))
    with GroundWorld(st, Constant(1.0, 0.0), P, WorldParams(n_ugv=1, ugv_model="husky")) as w:
        t = 0.0
        for _ in range(60):  # 3 s
            w.step(t, 0.05)
            t += 0.05
        s = w.states
    assert 1.5 < s.pos_ne[0, 0] < 3.0  # ~ 1 m/s after a 0.5 s ramp, wheels slip a little
    assert abs(s.pos_ne[0, 1]) < 0.2


def test_box_world_real_time_factor():
    st = initial_states(triangle_offsets(3))
    with GroundWorld(st, make_behaviour("route", 3, np.random.default_rng(0)), P) as w:
        t0 = time.perf_counter()
        for i in range(400):  # 20 s of simulation
            w.step(i * 0.05, 0.05)
        rtf = 20.0 / (time.perf_counter() - t0)
    assert rtf > 20.0  # measured ~120x on this machine; the issue saw ~67x


def test_bad_configuration_is_refused():
    st = initial_states(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="ugv_model"):
        GroundWorld(st, Constant(0, 0), P, WorldParams(n_ugv=2, ugv_model="tank"))
    with pytest.raises(ValueError, match="n_ugv"):
        GroundWorld(st, Constant(0, 0), P, WorldParams(n_ugv=3))
    with GroundWorld(st, Constant(0, 0), P, WorldParams(n_ugv=2)) as w:
        with pytest.raises(ValueError, match="dt"):
            w.step(0.0, math.nan)
    assert UGVModel().marker_top_m > UGVModel().height_m


def test_pybullet_world_is_deterministic_on_the_sim_clock():
    from skyherd.flight.clock import SimClock

    def run(seed):
        clock = SimClock()
        st = initial_states(triangle_offsets(3))
        with GroundWorld(st, make_behaviour("random", 3, np.random.default_rng(seed)), P) as w:
            for _ in range(200):
                w.step(clock.t, 0.05)
                clock.advance(50_000)
            return w.states.pos_ne.copy(), clock.t

    (a, ta), (b, _), (c, _) = run(3), run(3), run(4)
    assert ta == pytest.approx(10.0)
    assert np.array_equal(a, b)  # bit for bit
    assert not np.allclose(a, c)
