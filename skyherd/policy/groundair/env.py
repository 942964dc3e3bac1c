"""skyherd/GroundAir-v0: keep every UGV in the downward camera's view with a tight footprint.

One clock for air and ground: each step advances the UAV point model and the UGV formation by
dt = 0.5 s. Observation = φ(s) from the perception features (fast geometric path, no pixels;
`pixels=True` renders each frame with perception's OpenCV renderer and runs the detector on it),
plus the UAV's velocity and the change of φ since the last step, all in [0, 1]. Reward features
and metrics always come from the true geometry:

====  =============================================================
idx   observation (float32, shape (14,))
====  =============================================================
0–7   φ(s): com_u, com_v, spread, altitude, frac_in_view, all_in_view, edge_margin, frame_ok
      (perception.features; 0.5 = centred)
8–10  UAV velocity north, east, down: 0.5 + v / (2·v_max)
11–13 Δcom_u, Δcom_v, Δspread since the last step: 0.5 + 5·Δ, clipped
====  =============================================================

Reward features ψ(s) ∈ [0, 1]^9 (what IRL's reward wᵀψ is linear in; `reward_features`), a fixed
transform of φ: all_in_view, centred_u = 1 − 2|com_u − ½|, centred_v, edge_margin, and a one-hot
of the spread when all are in view, bins [0, .15), [.15, .3), [.3, .45), [.45, .6), [.6, 1].
The environment's own reward is w_taskᵀψ (TASK_WEIGHTS) unless `reward_weights` is given.

Episode end: truncation at `episode_s`; termination when no UGV was in view for `lost_s` (all
lost). Metrics (`episode_metrics`, also in the last step's info): all_in_view_frac = steps with
every UGV in view / max steps (a lost tail counts as out of view); footprint_ratio = mean over
all-in-view steps of the ground footprint area / area of the smallest circle around the UGVs;
ugv_losses = times a UGV left the view.
"""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

from skyherd.perception.features import FeatureParams
from skyherd.policy import register
from skyherd.policy.groundair.fastphi import LevelCamera, min_circle
from skyherd.policy.groundair.params import N_ACTIONS, TaskParams, action_velocity_ned
from skyherd.policy.groundair.scenarios import GROUNDSIM_SCENARIOS, SCENARIOS, Formation, make_team

register()  # skyherd/GroundAir-v0, wherever the environment's module is imported

OBS_DIM = 14
PSI_NAMES: tuple[str, ...] = (
    "all_in_view",
    "centred_u",
    "centred_v",
    "edge_margin",
    "spread_0_15",
    "spread_15_30",
    "spread_30_45",
    "spread_45_60",
    "spread_60_100",
)
N_PSI = len(PSI_NAMES)
SPREAD_EDGES = (0.15, 0.30, 0.45, 0.60)
TASK_WEIGHTS = np.array([1.0, 0.3, 0.3, 0.3, 0.0, 0.2, 0.4, 0.2, 0.0])


def reward_features(phi) -> list[float]:
    """ψ (9,) from φ (8,): see the module docstring."""
    k = phi[4]
    cu = 1.0 - 2.0 * abs(phi[0] - 0.5) if k > 0 else 0.0
    cv = 1.0 - 2.0 * abs(phi[1] - 0.5) if k > 0 else 0.0
    psi = [phi[5], cu, cv, phi[6], 0.0, 0.0, 0.0, 0.0, 0.0]
    if phi[5] > 0.5:
        s, b = phi[2], 0
        while b < len(SPREAD_EDGES) and s >= SPREAD_EDGES[b]:
            b += 1
        psi[4 + b] = 1.0
    return psi


def make_observation(phi, phi_prev, vel_ned, task: TaskParams) -> np.ndarray:
    """Observation (14,) float32 from φ (8,) now, φ at the previous step (None at the start) and
    the UAV velocity (north, east, down) [m/s]. The one definition used in training and in flight.
    """
    prev = phi_prev if phi_prev is not None else phi
    both = phi[4] > 0 and prev[4] > 0
    u = task.uav
    vm = (u.v_xy_mps, u.v_xy_mps, max(u.v_up_mps, u.v_down_mps))
    o = [float(x) for x in phi[:8]]
    o += [min(max(0.5 + float(v) / (2 * m), 0.0), 1.0) for v, m in zip(vel_ned, vm)]
    for j in (0, 1, 2):
        d = (phi[j] - prev[j]) if both else 0.0
        o.append(min(max(0.5 + 5.0 * d, 0.0), 1.0))
    return np.array(o, dtype=np.float32)


class _LevelPose:
    """A level UAV at (north, east, altitude) for the renderer: pos_ned (3,), quat (w, x, y, z)."""

    quat = np.array([1.0, 0.0, 0.0, 0.0])

    def __init__(self, n: float, e: float, alt: float):
        self.pos_ned = np.array([n, e, -alt])


class GroundAirEnv(gym.Env):
    """Fast path of the GroundAir task (see module docstring). Actions: params.ACTION_NAMES."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 2}

    def __init__(
        self,
        scenario: str = "composite",
        task: TaskParams | None = None,
        reward_weights=None,
        render_mode: str | None = None,
        start_noise: bool = True,
        pixels: bool = False,
        attitude: bool = False,
    ):
        if scenario not in SCENARIOS + GROUNDSIM_SCENARIOS:
            names = ", ".join(SCENARIOS + GROUNDSIM_SCENARIOS)
            raise ValueError(f"unknown scenario {scenario!r}; choose from {names}")
        self.scenario = scenario
        self.task = task or TaskParams()
        self.cam = LevelCamera(self.task.camera, FeatureParams())
        w = TASK_WEIGHTS if reward_weights is None else np.asarray(reward_weights, float)
        if w.shape != (N_PSI,) or not np.all(np.isfinite(w)):
            raise ValueError(f"reward_weights must be {N_PSI} finite numbers")
        self.w = [float(x) for x in w]
        self.render_mode = render_mode
        self.start_noise = start_noise
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(OBS_DIM,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(N_ACTIONS)
        u = self.task.uav
        self._decay = math.exp(-self.task.dt_s / u.tau_s)
        self._decay_z = math.exp(-self.task.dt_s / u.tau_z_s)
        self._cmds = [action_velocity_ned(a, u) for a in range(N_ACTIONS)]
        self.formation: Formation | None = None
        self.pixels = bool(pixels)
        self.attitude = bool(attitude)
        self._acc = (0.0, 0.0)
        self._renderer = self._detector = None
        if self.pixels:  # the perception pipeline: fast OpenCV renderer + marker detector
            from skyherd.perception.detector import Detector
            from skyherd.perception.render_fast import FastRenderer

            self._renderer = FastRenderer(self.task.camera)
            self._detector = Detector(self.task.camera, self.task.n_ugvs)

    # ---- state → observation
    def _observe(self):
        ugvs = self.formation.positions()
        det = self.formation.detectable()
        if self.attitude:
            phi, seen = self._phi_tilted(ugvs, det)
        else:
            phi, seen, _ = self.cam.phi(self.n, self.e, self.alt, ugvs, det)
        phi_obs = self._phi_from_pixels(ugvs, det) if self.pixels else phi
        o = make_observation(phi_obs, self._phi_prev, (self.vn, self.ve, self.vd), self.task)
        self._phi_prev = phi_obs
        return o, phi, seen, ugvs

    def quat(self) -> np.ndarray:
        """Attitude (w, x, y, z) body → NED: level, or (attitude=True) the tilt a multirotor
        needs for its horizontal acceleration a: pitch = −atan(a_n/g), roll = atan(a_e/g)."""
        if not self.attitude:
            return _LevelPose.quat
        from skyherd.flight.frames import euler_to_quat

        an, ae = self._acc
        return euler_to_quat(math.atan(ae / 9.80665), -math.atan(an / 9.80665), 0.0)

    def _phi_tilted(self, ugvs, detectable):
        """φ and seen flags through the body-fixed camera of a tilting UAV (perception's geometry)."""
        from skyherd.perception.camera import camera_pose
        from skyherd.perception.features import features_from_truth, true_centroids

        pts = np.array([[a, b, 0.0] for a, b in ugvs])
        pose = camera_pose(self.task.camera, np.array([self.n, self.e, -self.alt]), self.quat())
        phi = features_from_truth(self.task.camera, pose, pts, self.alt, detectable)
        _, seen = true_centroids(self.task.camera, pose, pts, detectable)
        return [float(x) for x in phi], [bool(x) for x in seen]

    def _phi_from_pixels(self, ugvs, detectable) -> list[float]:
        """φ from a rendered frame and the detector (pixels=True): what a real camera would give."""
        from skyherd.groundsim.ugv import UGVStates

        n = len(ugvs)
        camo = np.zeros(n, bool) if detectable is None else ~np.asarray(detectable, bool)
        states = UGVStates(np.asarray(ugvs, float), np.zeros(n), np.zeros(n), camo)
        pose = _LevelPose(self.n, self.e, self.alt)
        pose.quat = self.quat()
        frame = self._renderer.render(pose, states)
        self.last_frame = frame
        return [float(x) for x in self._detector.features(self._detector.detect(frame), self.alt)]

    def _bookkeep(self, phi, seen, ugvs) -> None:
        self._psi = reward_features(phi)
        if phi[5] > 0.5:
            self._in_view_steps += 1
            _, _, rm = min_circle(ugvs)
            z = self.alt - self.cam.off_d
            fp = (self.cam.W * z / self.cam.fx) * (self.cam.H * z / self.cam.fx)
            self._ratio_sum += fp / max(math.pi * rm * rm, 1e-6)
        if self._seen_prev is not None:
            self._losses += sum(1 for a, b in zip(self._seen_prev, seen) if a and not b)
        self._seen_prev = seen
        self._lost_s = 0.0 if phi[4] > 0 else self._lost_s + self.task.dt_s

    # ---- gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        rng = self.np_random
        self.formation = make_team(self.scenario, rng, self.task.n_ugvs)
        u = self.task.uav
        if isinstance(self.formation, Formation):  # the formation's centre and nominal radius
            cn, ce, r0 = 0.0, 0.0, self.formation.plan.radius(0.0)
        else:  # the smallest circle around the team
            cn, ce, r0 = min_circle(self.formation.positions())
        # start above the team at the altitude that frames it at the expert's spread target
        alt = self.cam.fx * max(r0, 2.0) / (self.task.spread_target * self.cam.half_diag)
        alt += self.cam.off_d
        if self.start_noise:
            self.n, self.e = cn + float(rng.uniform(-3, 3)), ce + float(rng.uniform(-3, 3))
            alt *= float(rng.uniform(0.9, 1.1))
        else:
            self.n, self.e = cn, ce
        self.alt = min(max(alt, u.alt_min_m), u.alt_max_m)
        self.vn = self.ve = self.vd = 0.0
        self._acc = (0.0, 0.0)
        self.steps = 0
        self._phi_prev = None
        self._seen_prev = None
        self._in_view_steps = 0
        self._ratio_sum = 0.0
        self._losses = 0
        self._lost_s = 0.0
        obs, phi, seen, ugvs = self._observe()
        self._bookkeep(phi, seen, ugvs)
        self._in_view_steps = 0  # metrics count the steps taken, not the start state
        self._ratio_sum = 0.0
        return obs, {"phi": phi, "psi": self._psi}

    def step(self, action):
        a = int(action)
        if not 0 <= a < N_ACTIONS:
            raise ValueError(f"action must be in 0..{N_ACTIONS - 1}, got {action}")
        return self.step_velocity(self._cmds[a])

    def step_velocity(self, cmd_ned):
        """One step with the commanded velocity (north, east, down) [m/s] held for dt: the one
        way the UAV moves (a discrete action is its row of `action_velocity_ned`; continuous
        actions, policy.absdl.env, and other pilots, e.g. policy.search, pass their own
        command). The caller keeps it within the envelope's limits. Same returns as `step`."""
        cn, ce, cd = (float(x) for x in cmd_ned)
        if not all(math.isfinite(x) for x in (cn, ce, cd)):
            raise ValueError(f"velocity command must be finite, got {cmd_ned}")
        dt, k, kz = self.task.dt_s, self._decay, self._decay_z
        # exact solution of v' = (v_cmd − v)/τ over dt, and of the position it drives
        g = self.task.uav.tau_s * (1.0 - k)
        gz = self.task.uav.tau_z_s * (1.0 - kz)
        self.n += cn * dt + (self.vn - cn) * g
        self.e += ce * dt + (self.ve - ce) * g
        self.alt -= cd * dt + (self.vd - cd) * gz
        self._acc = (
            (cn - self.vn) * k / self.task.uav.tau_s,
            (ce - self.ve) * k / self.task.uav.tau_s,
        )
        self.vn = cn + (self.vn - cn) * k
        self.ve = ce + (self.ve - ce) * k
        self.vd = cd + (self.vd - cd) * kz
        u = self.task.uav
        if self.alt < u.alt_min_m or self.alt > u.alt_max_m:  # geofence: hold the altitude limit
            self.alt = min(max(self.alt, u.alt_min_m), u.alt_max_m)
            self.vd = 0.0
        self.formation.step(dt)
        self.steps += 1
        obs, phi, seen, ugvs = self._observe()
        self._bookkeep(phi, seen, ugvs)
        psi = self._psi
        r = sum(wi * x for wi, x in zip(self.w, psi))
        terminated = self._lost_s >= self.task.lost_s - 1e-9
        truncated = self.steps >= self.task.max_steps
        info = {"phi": phi, "psi": psi}
        if terminated or truncated:
            info["metrics"] = self.episode_metrics()
        return obs, r, terminated, truncated, info

    def episode_metrics(self) -> dict[str, float]:
        n = self._in_view_steps
        return {
            "all_in_view_frac": n / self.task.max_steps,
            "footprint_ratio": self._ratio_sum / n if n else math.nan,
            "ugv_losses": float(self._losses),
            "steps": float(self.steps),
        }

    def uav_state(self) -> dict[str, float]:
        """UAV position NED [m] and velocity NED [m/s] (for demos, plots and tests)."""
        return {
            "n": self.n,
            "e": self.e,
            "d": -self.alt,
            "vn": self.vn,
            "ve": self.ve,
            "vd": self.vd,
        }

    def render(self):
        if self.render_mode != "rgb_array":
            return None
        import cv2

        W, H = self.cam.W, self.cam.H
        img = np.full((H, W, 3), (90, 140, 90), np.uint8)
        uv, seen = self.cam.pixels(self.n, self.e, self.alt, self.formation.positions())
        for (u, v), s in zip(uv, seen):
            if s:
                cv2.circle(img, (int(round(u)), int(round(v))), 4, (255, 40, 40), -1)
        cv2.circle(img, (int(self.cam.cx), int(self.cam.cy)), 2, (255, 0, 0), -1)
        return img
