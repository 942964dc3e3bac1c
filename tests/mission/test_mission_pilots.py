"""The mission layer's pilots (the PID follower's signs, the policy's action map, the square's
waypoints) and the level camera mount the quadrotor's pilots see through."""

import math

import numpy as np

from skyherd.flight.frames import euler_to_quat, quat_to_euler
from skyherd.flight.state import VehicleState
from skyherd.mission.pilots import Observation, PerceptionFollower, PolicyPilot, WaypointPilot
from skyherd.perception.camera import camera_pose, project
from skyherd.perception.features import features_from_truth
from skyherd.perception.mount import mounted_pose
from skyherd.task.params import TaskParams, action_velocity_ned


def _phi(com_u=0.5, com_v=0.5, spread=0.35, seen=1.0):
    return np.array([com_u, com_v, spread, 0.4, seen, 1.0 if seen >= 1 else 0.0, 0.3, 1.0])


def _state(pos=(0.0, 0.0, -20.0)):
    return VehicleState(
        0.0, np.array(pos), np.zeros(3), np.array([1.0, 0, 0, 0]), np.zeros(3), np.zeros(3), False
    )


class _Call:
    """Old-style call of a pilot: (obs, φ, dt) → (action, NED velocity)."""

    def __init__(self, pilot):
        self.pilot = pilot

    def __call__(self, obs, phi, dt, t=0.0):
        p = self.pilot.propose(Observation(t, _state(), phi, obs, dt))
        return p.action, p.setpoint.vel_ned


def test_follower_moves_toward_the_team_and_holds_the_spread():
    task = TaskParams()
    f = _Call(PerceptionFollower(task))
    _, v = f(None, _phi(com_u=0.7), 0.5)  # team right of centre = east of the UAV
    assert v[1] > 0 and abs(v[0]) < 1e-9 and abs(v[2]) < 1e-9
    f = _Call(PerceptionFollower(task))
    _, v = f(None, _phi(com_v=0.3), 0.5)  # team above centre = north of the UAV
    assert v[0] > 0 and abs(v[1]) < 1e-9
    _, v = _Call(PerceptionFollower(task))(None, _phi(spread=0.6), 0.5)  # too spread: climb
    assert v[2] < 0
    _, v = _Call(PerceptionFollower(task))(None, _phi(spread=0.1), 0.5)  # too tight: descend
    assert v[2] > 0
    _, v = _Call(PerceptionFollower(task))(None, _phi(com_u=1.0, com_v=0.0, spread=1.0), 0.5)
    u = task.uav
    assert abs(v[0]) <= u.v_xy_mps and abs(v[1]) <= u.v_xy_mps and -v[2] <= u.v_up_mps
    _, v = _Call(PerceptionFollower(task))(None, _phi(seen=0.0), 0.5)  # nothing seen: climb, hold
    assert v[2] < 0 and v[0] == 0 and v[1] == 0


def test_follower_signs_agree_with_the_camera():
    """A UGV north-east of the UAV appears up-right in the image, and the follower flies there."""
    task = TaskParams()
    cam = task.camera
    uav = np.array([0.0, 0.0, -25.0])
    ugvs = np.array([[6.0, 4.0], [7.0, 5.0], [5.0, 6.0]])
    pose = camera_pose(cam, uav, euler_to_quat(0, 0, 0))
    points = np.c_[ugvs, np.zeros(3)]
    uv, _ = project(cam, pose, points)
    assert np.all(uv[:, 0] > cam.cx) and np.all(uv[:, 1] < cam.cy)
    phi = features_from_truth(cam, pose, points, altitude_m=25.0)
    _, v = _Call(PerceptionFollower(task))(None, phi, 0.5)
    assert v[0] > 0 and v[1] > 0


def test_policy_pilot_maps_actions_as_in_training():
    task = TaskParams()
    pilot = _Call(PolicyPilot(lambda obs: 3, task))
    a, v = pilot(np.zeros(14), _phi(), 0.5)
    assert a == 3 and np.allclose(v, action_velocity_ned(3, task.uav))


def test_stabilised_camera_keeps_heading_and_levels():
    q = euler_to_quat(0.4, -0.3, 1.2)
    s = VehicleState(0.0, np.zeros(3), np.zeros(3), q, np.zeros(3), np.zeros(3), False)
    level = mounted_pose(TaskParams().camera, "level", s.pos_ned, s.quat)
    r, p, y = quat_to_euler(level.quat)
    assert abs(r) < 1e-12 and abs(p) < 1e-12 and math.isclose(y, 1.2)


def test_waypoint_pilot_settles_at_each_corner_before_the_next():
    wps = [np.array([10.0, 0.0, -5.0]), np.array([10.0, 10.0, -5.0])]
    pilot = WaypointPilot(wps, accept_m=1.0, settle_s=1.0)

    def at(t, pos):
        return pilot.propose(Observation(t, _state(pos), None, np.zeros(0), 0.5)).setpoint.pos_ned

    assert np.allclose(at(0.0, (0, 0, -5)), wps[0])
    assert np.allclose(at(0.5, (9.5, 0, -5)), wps[0])  # inside, not settled yet
    assert np.allclose(at(1.0, (9.6, 0, -5)), wps[0])
    assert np.allclose(at(1.5, (9.7, 0, -5)), wps[1]) and pilot.reached == [1.5]
    assert not pilot.done
    at(2.0, (10, 10, -5)), at(3.0, (10, 10, -5))
    assert pilot.done and pilot.reached == [1.5, 3.0]
