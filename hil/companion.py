"""The companion computer of the ground–air mission: camera → perception → policy → safety net.

One `update(t, state)` per vehicle telemetry sample (simulation time t [s], the vehicle's
clock, so air and ground share one clock at any speed-up):

1. the UGV team moves to time t;
2. at the camera rig's rate the downward camera renders a frame, publishes it on Zenoh and the
   detector turns it into features φ(s);
3. every decision period (the task's, 0.5 s) the pilot proposes an NED velocity: the learned
   policy from the observation (φ, velocity, Δφ), mapped exactly as in training, or the
   classic PID follower from φ;
4. the safety net's supervisor certifies it; what leaves is the offboard setpoint (or the
   airframe fallback, flagged so the caller can put the autopilot in its own HOLD mode).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from flight.autopilot_api import FlightMode, Setpoint
from flight.frames import euler_to_quat
from flight.state import VehicleState
from groundsim.ugv import UGVStates
from perception.pipeline import CameraRig, CameraTick
from policy.groundair.env import make_observation
from policy.groundair.params import TaskParams, action_velocity_ned
from safety.supervisor import Decision, Health, Supervisor


@dataclass(frozen=True)
class CompanionParams:
    """Companion settings (the camera rate is the rig's, the decision period the task's)."""

    yaw: float = 0.0  # commanded heading [rad]; the policy was trained heading north
    gimbal: bool = True  # roll/pitch-stabilised camera (the policy was trained with a level one)


@dataclass
class CompanionSample:
    """What happened at one decision, for metrics and plots."""

    t: float
    phi: np.ndarray
    action: int
    decision: Decision
    ugvs_ne: np.ndarray


def level_camera_mount(state: VehicleState) -> VehicleState:
    """The state as a 2-axis (roll, pitch) stabilised gimbal sees it: heading kept, level.

    A body-fixed camera swings the view by the tilt the autopilot needs to accelerate (tens of
    degrees for the policy's velocity steps, metres on the ground at 20 m); the gimbal removes
    that, as on most camera drones, so the image is the level view the policy was trained on.
    """
    _, _, yaw = state.euler
    return dataclasses.replace(state, quat=euler_to_quat(0.0, 0.0, yaw))


class PolicyPilot:
    """The learned policy: observation → discrete action → NED velocity, exactly as in training."""

    def __init__(self, policy: Callable[[np.ndarray], int], task: TaskParams):
        self.policy, self.task = policy, task

    def __call__(self, obs: np.ndarray, phi: np.ndarray, dt: float) -> tuple[int, np.ndarray]:
        a = int(self.policy(obs))
        return a, np.array(action_velocity_ned(a, self.task.uav))


@dataclass(frozen=True)
class FollowerGains:
    """PID follower on image features (φ entries are normalised to [0, 1])."""

    kp_xy: float = 12.0  # [m/s] per unit of centre-of-mass offset (0.5 = image edge)
    ki_xy: float = 1.0  # [m/s per s] per unit offset
    kd_xy: float = 4.0  # [m/s] per unit offset change per s
    kp_z: float = 10.0  # [m/s] per unit of spread error (climb when the team spreads)
    search_climb_mps: float = 1.0  # climb to widen the view while no UGV is seen [m/s]


class PerceptionFollower:
    """The classic pilot: centre the UGVs' centre of mass and hold the spread at the target.

    Image right is east and image up is north (level camera, heading north), so
        v_east = PID(com_u − ½),  v_north = −PID(com_v − ½),  v_down = −kp_z·(spread − target),
    each clipped to the policy's own speed commands. With no UGV in view it climbs to search.
    """

    def __init__(self, task: TaskParams, gains: FollowerGains = FollowerGains()):
        self.task, self.g = task, gains
        self.integral = np.zeros(2)
        self.prev: np.ndarray | None = None

    def __call__(self, obs: np.ndarray, phi: np.ndarray, dt: float) -> tuple[int, np.ndarray]:
        u, g = self.task.uav, self.g
        if phi[4] <= 0.0:  # nothing seen: hold position, climb to search
            self.integral[:] = 0.0
            self.prev = None
            return -1, np.array([0.0, 0.0, -min(g.search_climb_mps, u.v_up_mps)])
        e = np.array([phi[0] - 0.5, phi[1] - 0.5])  # (right, down) in the image
        self.integral = np.clip(self.integral + e * dt, -2.0, 2.0)
        de = np.zeros(2) if self.prev is None or dt <= 0 else (e - self.prev) / dt
        self.prev = e
        right, down = g.kp_xy * e + g.ki_xy * self.integral + g.kd_xy * de
        v_down = -g.kp_z * (phi[2] - self.task.spread_target)
        return -1, np.array([
            float(np.clip(-down, -u.v_xy_mps, u.v_xy_mps)),
            float(np.clip(right, -u.v_xy_mps, u.v_xy_mps)),
            float(np.clip(v_down, -u.v_up_mps, u.v_down_mps)),
        ])  # fmt: skip


class GroundAirCompanion:
    """Flies a ground–air pilot (learned policy or PID follower) behind the safety net."""

    def __init__(
        self,
        task: TaskParams,
        team,
        pilot: Callable[[np.ndarray, np.ndarray, float], tuple[int, np.ndarray]],
        supervisor: Supervisor,
        rig: CameraRig,
        params: CompanionParams = CompanionParams(),
        world=None,
    ):
        self.task, self.team, self.pilot = task, team, pilot
        self.supervisor, self.rig = supervisor, rig
        self.world = world  # a groundsim.world.GroundWorld mirrored for PyBullet pixels, or None
        self.p = params
        self.t0: float | None = None
        self.t_ground = 0.0
        self.t_frame: float | None = None
        self.t_decision: float | None = None
        self.phi: np.ndarray | None = None
        self.phi_prev: np.ndarray | None = None  # φ at the previous decision
        self.last_tick: CameraTick | None = None
        self.action = 0
        self.samples: list[CompanionSample] = []
        self.link_t: float | None = None

    # ---- the UGV team on the shared clock ------------------------------------------------
    def ugv_states(self) -> UGVStates:
        return self.team_states(self.team)

    @staticmethod
    def team_states(team) -> UGVStates:
        """The team's UGVs as groundsim states: a groundsim world's own states (headings,
        camouflage), or a Formation's (heading along the team's motion)."""
        if hasattr(team, "world"):
            return team.world.states
        pos = np.array(team.positions(), dtype=float)
        vn, ve = team.centre_velocity
        n = len(pos)
        return UGVStates(
            pos_ne=pos,
            heading=np.full(n, math.atan2(ve, vn)),
            speed=np.full(n, math.hypot(vn, ve)),
            camouflaged=np.zeros(n, dtype=bool),
        )

    def _advance_ground(self, t_rel: float) -> None:
        dt = t_rel - self.t_ground
        if dt > 0:
            self.team.step(dt)
            self.t_ground = t_rel

    # ---- camera and perception -----------------------------------------------------------
    def _camera(self, t: float, state: VehicleState) -> None:
        if not self.rig.due(t):
            return
        ugvs = self.ugv_states()
        if self.world is not None:
            self.world.place(ugvs)  # PyBullet pixels of the same team
        uav = level_camera_mount(state) if self.p.gimbal else state
        tick = self.rig.tick(t, uav, ugvs)
        if tick is None:
            return
        self.last_tick = tick
        self.phi = tick.phi
        self.t_frame = t

    def observation(self, state: VehicleState) -> np.ndarray:
        """(φ, velocity, Δφ since the last decision), built by the training environment's code."""
        return make_observation(self.phi, self.phi_prev, state.vel_ned, self.task)

    # ---- one telemetry sample --------------------------------------------------------------
    def update(self, t: float, state: VehicleState) -> Decision:
        """Vehicle time t [s] and state → the certified decision to fly now."""
        if self.t0 is None:
            self.t0 = t
        self._advance_ground(t - self.t0)
        self._camera(t, state)
        proposed = None
        if self.t_decision is None or t - self.t_decision >= self.task.dt_s - 1e-9:
            self.t_decision = t
            self.action, vel = self.pilot(self.observation(state), self.phi, self.task.dt_s)
            self.phi_prev = self.phi  # Δφ is taken over one decision period, as in training
            proposed = Setpoint(vel_ned=vel, yaw=self.p.yaw)
        health = Health(camera_t=self.t_frame, link_t=self.link_t if self.link_t is not None else t)
        decision = self.supervisor.update(t, state, proposed, health)
        if proposed is not None:
            self.samples.append(
                CompanionSample(t, self.phi.copy(), self.action, decision, self.ugv_states().pos_ne)
            )
        return decision

    @property
    def wants_hold(self) -> bool:
        """True while the safety net's fallback is flying (map to the autopilot's HOLD)."""
        return bool(self.samples) and self.samples[-1].decision.autopilot_mode is FlightMode.HOLD
