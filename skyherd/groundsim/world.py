"""The headless PyBullet ground world: a flat field and N UGVs with coloured top markers.

- Own physics client in DIRECT mode (never the global default client), quiet: PyBullet's C
  code prints to the process's stdout (build banner, URDF warnings); those writes are sent to
  /dev/null while PyBullet is imported and models are loaded.
- PyBullet's world is z-up ENU. Every conversion goes through `flight.frames` (ned_to_enu,
  enu_to_ned, yaw_ned_to_enu, yaw_enu_to_ned); the rest of skyherd sees NED only.
- `step(t, dt)`: t is the shared SimClock's time [s] at the start of the step, dt [s]. The
  behaviour is asked for a command once per step (the controller rate); physics sub-steps at
  `physics_dt`.
- UGV models (`WorldParams.ugv_model`):
  * "box" (default): a dark box hull with a square top marker; driven like a hovercraft on a
    frictionless field by setting its base velocity to the unicycle command each sub-step (the
    speed slews at DriveParams.accel_max). Contacts and collisions are PyBullet's. Fast (~70×
    real time for 3 UGVs measured in the issue; see bench/bench_perception.py).
  * "husky": Clearpath Husky URDF from pybullet_data, four wheels under velocity control from
    the differential-drive wheel speeds, with a marker plate carried above it. Slow (~4× real
    time) and only for realism checks.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
from dataclasses import dataclass

import numpy as np

from skyherd.flight.frames import enu_to_ned, ned_to_enu, yaw_enu_to_ned, yaw_ned_to_enu
from skyherd.groundsim.behaviours import Behaviour, DriveParams, wheel_speeds
from skyherd.groundsim.ugv import (
    BODY_RGB,
    GROUND_RGB,
    MARKER_COLOURS,
    UGVModel,
    UGVStates,
)


@contextlib.contextmanager
def quiet_stdout():
    """Send the process's fds 1 and 2 to /dev/null inside the block (C-level prints too).

    Only PyBullet's chatter runs inside (banner, URDF warnings); its real failures still
    surface as Python exceptions.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    devnull = os.open(os.devnull, os.O_WRONLY)
    saved = [os.dup(1), os.dup(2)]
    try:
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in (*saved, devnull):
            os.close(fd)


def import_pybullet():
    """pybullet, imported without its build banner on stdout."""
    if "pybullet" in sys.modules:
        return sys.modules["pybullet"]
    with quiet_stdout():
        import pybullet
    return pybullet


def rgba(rgb: tuple[int, int, int]) -> list[float]:
    return [rgb[0] / 255.0, rgb[1] / 255.0, rgb[2] / 255.0, 1.0]


HUSKY_WHEEL_RADIUS_M = 0.17775  # from husky.urdf
HUSKY_TRACK_M = 2 * 0.2854  # from husky.urdf
HUSKY_BASE_HEIGHT_M = 0.145  # base_link above the ground at rest (wheel radius − axle offset)


@dataclass(frozen=True)
class WorldParams:
    n_ugv: int = 3
    ugv_model: str = "box"  # "box" or "husky"
    physics_dt: float = 0.02  # PyBullet sub-step [s]
    ground_half_m: float = 500.0  # the field is a square of this half-size [m]
    gravity: float = 9.81  # [m/s^2]


class GroundWorld:
    """PyBullet ground world. Positions in and out are NED; the ENU side stays inside."""

    def __init__(
        self,
        initial: UGVStates,
        behaviour: Behaviour,
        drive: DriveParams | None = None,
        params: WorldParams | None = None,
        model: UGVModel | None = None,
    ):
        self.p = params if params is not None else WorldParams()
        self.drive = drive if drive is not None else DriveParams()
        self.model = model if model is not None else UGVModel()
        if self.p.ugv_model not in ("box", "husky"):
            raise ValueError(f"ugv_model must be 'box' or 'husky', got {self.p.ugv_model!r}")
        if initial.n != self.p.n_ugv:
            raise ValueError(f"{initial.n} initial states for n_ugv={self.p.n_ugv}")
        self.behaviour = behaviour
        self.pb = import_pybullet()
        self.cid = self.pb.connect(self.pb.DIRECT)
        self._camo = np.zeros(self.p.n_ugv, dtype=bool)
        self.ground_id = -1
        self.bodies: list[int] = []
        self.markers: list[int] = []  # husky only: the carried marker plates
        with quiet_stdout():
            self._build(initial)
        self._speed = initial.speed.astype(float).copy()
        self.states = self.read_states()

    # -- construction -------------------------------------------------------------------
    def _build(self, initial: UGVStates) -> None:
        pb, c = self.pb, self.cid
        pb.setGravity(0, 0, -self.p.gravity, physicsClientId=c)
        pb.setTimeStep(self.p.physics_dt, physicsClientId=c)
        g = self.p.ground_half_m
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[g, g, 0.05], physicsClientId=c)
        vis = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=[g, g, 0.05], rgbaColor=rgba(GROUND_RGB), physicsClientId=c
        )
        self.ground_id = pb.createMultiBody(0, col, vis, [0, 0, -0.05], physicsClientId=c)
        for i in range(self.p.n_ugv):
            pos = ned_to_enu(np.array([initial.pos_ne[i, 0], initial.pos_ne[i, 1], 0.0]))
            yaw = yaw_ned_to_enu(float(initial.heading[i]))
            colour = rgba(MARKER_COLOURS[i % len(MARKER_COLOURS)])
            if self.p.ugv_model == "box":
                body = self._box_ugv(pos, yaw, colour)
            else:
                body = self._husky_ugv(pos, yaw, colour)
            self.bodies.append(body)
        if self.p.ugv_model == "box":
            pb.changeDynamics(self.ground_id, -1, lateralFriction=0.0, physicsClientId=c)

    def _box_ugv(self, pos_enu: np.ndarray, yaw_enu: float, colour: list[float]) -> int:
        pb, c, m = self.pb, self.cid, self.model
        hx, hy, hz = 0.5 * m.length_m, 0.5 * m.width_m, 0.5 * m.height_m
        col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[hx, hy, hz], physicsClientId=c)
        half_marker = [0.5 * m.marker_size_m, 0.5 * m.marker_size_m, 0.5 * m.marker_thickness_m]
        vis = pb.createVisualShapeArray(
            shapeTypes=[pb.GEOM_BOX, pb.GEOM_BOX],
            halfExtents=[[hx, hy, hz], half_marker],
            rgbaColors=[rgba(BODY_RGB), colour],
            visualFramePositions=[[0, 0, 0], [0, 0, hz + 0.5 * m.marker_thickness_m]],
            physicsClientId=c,
        )
        q = pb.getQuaternionFromEuler([0, 0, yaw_enu])
        body = pb.createMultiBody(
            m.mass_kg, col, vis, [pos_enu[0], pos_enu[1], hz + 1e-3], q, physicsClientId=c
        )
        pb.changeDynamics(
            body, -1, lateralFriction=0.0, linearDamping=0.0, angularDamping=0.0,
            physicsClientId=c,
        )  # fmt: skip
        return body

    def _husky_ugv(self, pos_enu: np.ndarray, yaw_enu: float, colour: list[float]) -> int:
        import pybullet_data

        pb, c, m = self.pb, self.cid, self.model
        q = pb.getQuaternionFromEuler([0, 0, yaw_enu])
        path = os.path.join(pybullet_data.getDataPath(), "husky", "husky.urdf")
        if not os.path.exists(path):
            raise ValueError(f"ugv_model 'husky' needs {path} (pybullet_data); use 'box'")
        body = pb.loadURDF(
            path, [pos_enu[0], pos_enu[1], HUSKY_BASE_HEIGHT_M + 0.02], q, physicsClientId=c
        )
        half = [0.5 * m.marker_size_m, 0.5 * m.marker_size_m, 0.5 * m.marker_thickness_m]
        vis = pb.createVisualShape(
            pb.GEOM_BOX, halfExtents=half, rgbaColor=colour, physicsClientId=c
        )
        marker = pb.createMultiBody(
            0, -1, vis, self._husky_marker_pos(pos_enu), q, physicsClientId=c
        )
        self.markers.append(marker)
        return body

    def _husky_marker_pos(self, base_enu) -> list[float]:
        m = self.model
        return [base_enu[0], base_enu[1], m.marker_top_m - 0.5 * m.marker_thickness_m]

    # -- state --------------------------------------------------------------------------
    def read_states(self) -> UGVStates:
        """UGV states in NED from PyBullet's ENU bodies."""
        pb, c = self.pb, self.cid
        n = self.p.n_ugv
        pos, hd, spd = np.empty((n, 2)), np.empty(n), np.empty(n)
        for i, b in enumerate(self.bodies):
            p_enu, q = pb.getBasePositionAndOrientation(b, physicsClientId=c)
            v_enu, _ = pb.getBaseVelocity(b, physicsClientId=c)
            p_ned = enu_to_ned(np.array(p_enu))
            v_ned = enu_to_ned(np.array(v_enu))
            yaw = yaw_enu_to_ned(pb.getEulerFromQuaternion(q)[2])
            pos[i] = p_ned[:2]
            hd[i] = yaw
            spd[i] = v_ned[0] * math.cos(yaw) + v_ned[1] * math.sin(yaw)
        return UGVStates(pos, hd, spd, self._camo.copy())

    def place(self, states: UGVStates) -> None:
        """Teleport the UGVs to `states` (NED), velocities zeroed, camouflage applied."""
        pb, c = self.pb, self.cid
        z0 = 0.5 * self.model.height_m if self.p.ugv_model == "box" else HUSKY_BASE_HEIGHT_M
        for i, b in enumerate(self.bodies):
            p_enu = ned_to_enu(np.array([states.pos_ne[i, 0], states.pos_ne[i, 1], 0.0]))
            p_enu[2] = z0
            q = pb.getQuaternionFromEuler([0, 0, yaw_ned_to_enu(float(states.heading[i]))])
            pb.resetBasePositionAndOrientation(b, p_enu.tolist(), q, physicsClientId=c)
            pb.resetBaseVelocity(b, [0, 0, 0], [0, 0, 0], physicsClientId=c)
        self.set_camouflage(states.camouflaged)
        self._speed = np.zeros(self.p.n_ugv)
        if self.p.ugv_model == "husky":
            self._carry_markers()
        self.states = self.read_states()

    def set_camouflage(self, camo: np.ndarray) -> None:
        """Marker i takes the ground's colour while camo[i] (visible to the PyBullet camera)."""
        pb, c = self.pb, self.cid
        for i, flag in enumerate(np.asarray(camo, dtype=bool)):
            if flag == self._camo[i]:
                continue
            colour = rgba(GROUND_RGB) if flag else rgba(MARKER_COLOURS[i % len(MARKER_COLOURS)])
            if self.p.ugv_model == "box":
                pb.changeVisualShape(
                    self.bodies[i], -1, shapeIndex=1, rgbaColor=colour, physicsClientId=c
                )
            else:
                pb.changeVisualShape(self.markers[i], -1, rgbaColor=colour, physicsClientId=c)
            self._camo[i] = flag

    def step(self, t: float, dt: float) -> UGVStates:
        """Advance the ground by dt [s] from shared simulation time t [s]; returns NED states."""
        if not (dt > 0 and math.isfinite(dt)):
            raise ValueError(f"dt must be finite and > 0, got {dt}")
        cmd = self.behaviour.command(t, self.states)
        self.set_camouflage(cmd.camouflaged)
        d = self.drive
        w = np.clip(cmd.omega, -d.omega_max, d.omega_max)
        n_sub = max(1, int(round(dt / self.p.physics_dt)))
        h = dt / n_sub
        self.pb.setTimeStep(h, physicsClientId=self.cid)
        for _ in range(n_sub):
            dv = np.clip(cmd.v - self._speed, -d.accel_max * h, d.accel_max * h)
            self._speed = np.clip(self._speed + dv, 0.0, d.v_max)
            if self.p.ugv_model == "box":
                self._drive_boxes(self._speed, w)
            else:
                self._drive_huskies(self._speed, w)
            self.pb.stepSimulation(physicsClientId=self.cid)
        self.states = self.read_states()
        if self.p.ugv_model == "husky":
            self._carry_markers()
        return self.states

    def _drive_boxes(self, v: np.ndarray, omega: np.ndarray) -> None:
        pb, c = self.pb, self.cid
        for i, b in enumerate(self.bodies):
            _, q = pb.getBasePositionAndOrientation(b, physicsClientId=c)
            psi = yaw_enu_to_ned(pb.getEulerFromQuaternion(q)[2])
            v_enu = ned_to_enu(np.array([v[i] * math.cos(psi), v[i] * math.sin(psi), 0.0]))
            vz = pb.getBaseVelocity(b, physicsClientId=c)[0][2]
            # NED yaw rate ω (clockwise seen from above) is −ω about ENU z (up).
            pb.resetBaseVelocity(
                b, [v_enu[0], v_enu[1], vz], [0.0, 0.0, -float(omega[i])], physicsClientId=c
            )

    def _drive_huskies(self, v: np.ndarray, omega: np.ndarray) -> None:
        pb, c = self.pb, self.cid
        left, right = wheel_speeds(v, omega, HUSKY_TRACK_M)
        for i, b in enumerate(self.bodies):
            wl, wr = left[i] / HUSKY_WHEEL_RADIUS_M, right[i] / HUSKY_WHEEL_RADIUS_M
            for joint, rate in ((2, wl), (3, wr), (4, wl), (5, wr)):
                pb.setJointMotorControl2(
                    b, joint, pb.VELOCITY_CONTROL, targetVelocity=rate, force=100.0,
                    physicsClientId=c,
                )  # fmt: skip

    def _carry_markers(self) -> None:
        pb, c = self.pb, self.cid
        for b, mk in zip(self.bodies, self.markers):
            p_enu, q = pb.getBasePositionAndOrientation(b, physicsClientId=c)
            yaw = pb.getEulerFromQuaternion(q)[2]
            pb.resetBasePositionAndOrientation(
                mk, self._husky_marker_pos(p_enu), pb.getQuaternionFromEuler([0, 0, yaw]),
                physicsClientId=c,
            )  # fmt: skip

    def close(self) -> None:
        if self.cid >= 0:
            with contextlib.suppress(Exception):
                self.pb.disconnect(physicsClientId=self.cid)
            self.cid = -1

    def __enter__(self) -> GroundWorld:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        with contextlib.suppress(Exception):
            self.close()
