"""Continuous velocity actions in skyherd/GroundAir-v0.

The base environment (policy.groundair.env) moves the UAV with `step_velocity(v_ned)`; its
discrete actions are seven rows of that command. Here the action is the command itself,
(north, east, down) [m/s], bounded by the tighter of the quadrotor autopilot's limits
(flight.multirotor.params: MPC_XY_VEL_MAX, MPC_Z_VEL_MAX_UP, MPC_Z_VEL_MAX_DN) and the flown
envelope's rows (safety/envelopes/quadrotor_groundair.toml: speed_h, climb, descent). The
horizontal bound is on the speed (a disc), the vertical on each direction. The observation, the
reward and the metrics are the base environment's; `info["command"]` is the flown command.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import gymnasium as gym
import numpy as np

from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.task.params import TaskParams, autopilot_velocity_limits

ENVELOPE_FILE = "quadrotor_groundair.toml"
"""The constraint set `skyherd fly` flies the ground-air mission in (safety/envelopes/)."""


@dataclass(frozen=True)
class VelocityLimits:
    """Bounds of a continuous command [m/s]: horizontal speed, climb rate, descent rate."""

    h_mps: float
    up_mps: float
    down_mps: float

    def clip(self, v) -> np.ndarray:
        """(3,) NED command → the nearest command inside the bounds."""
        v = np.asarray(v, float).copy()
        h = float(np.hypot(v[0], v[1]))
        if h > self.h_mps:
            v[:2] *= self.h_mps / h
        v[2] = min(max(v[2], -self.up_mps), self.down_mps)
        return v

    @property
    def scale(self) -> np.ndarray:
        """Per-axis scale that maps the bounds to about ±1 (the networks' output units)."""
        return np.array([self.h_mps, self.h_mps, max(self.up_mps, self.down_mps)])


@lru_cache(maxsize=1)
def velocity_limits() -> VelocityLimits:
    """min(autopilot, envelope) on each bound, read from their one source each."""
    from skyherd.safety.config import ENVELOPE_DIR, load_envelope

    ap = autopilot_velocity_limits()
    spec, _ = load_envelope(ENVELOPE_DIR / ENVELOPE_FILE)
    lim = spec.limits
    return VelocityLimits(
        h_mps=min(ap["xy"], lim.speed_h_mps),
        up_mps=min(ap["up"], lim.climb_mps),
        down_mps=min(ap["down"], lim.descent_mps),
    )


class ContinuousGroundAirEnv(gym.Env):
    """GroundAir with a Box(3) action: a NED velocity command [m/s], clipped to the limits."""

    metadata = GroundAirEnv.metadata

    def __init__(self, scenario: str = "composite", task: TaskParams | None = None, **kw):
        self.base = GroundAirEnv(scenario, task=task, **kw)
        self.task = self.base.task
        self.limits = velocity_limits()
        lo = np.array([-self.limits.h_mps, -self.limits.h_mps, -self.limits.up_mps], np.float32)
        hi = np.array([self.limits.h_mps, self.limits.h_mps, self.limits.down_mps], np.float32)
        self.action_space = gym.spaces.Box(lo, hi, dtype=np.float32)
        self.observation_space = self.base.observation_space

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        return self.base.reset(seed=seed, options=options)

    def step(self, action):
        v = self.limits.clip(action)
        if not np.all(np.isfinite(v)):
            raise ValueError(f"velocity command must be finite, got {action}")
        obs, r, term, trunc, info = self.base.step_velocity(v)
        info["command"] = v
        return obs, r, term, trunc, info

    def uav_state(self) -> dict[str, float]:
        return self.base.uav_state()

    def episode_metrics(self) -> dict[str, float]:
        return self.base.episode_metrics()
