"""Learned UAV policies: the GroundAir task, DQN, projection IRL and Apprenticeship Bootstrapping.

Importing `policy` registers `skyherd/GroundAir-v0` with gymnasium (light: no torch import).
"""

from __future__ import annotations

import gymnasium as gym

ENV_ID = "skyherd/GroundAir-v0"

if ENV_ID not in gym.envs.registry:
    gym.register(
        id=ENV_ID, entry_point="skyherd.policy.groundair.env:GroundAirEnv", max_episode_steps=None
    )


def load_policy(path):
    """Load a trained policy file → callable(obs (14,)) → action index (policy.groundair.params).

    Build obs with policy.groundair.env.make_observation; map the action to an offboard velocity
    setpoint with policy.groundair.params.action_velocity_ned. numpy only (no torch).
    """
    from skyherd.policy.dqn import load_policy as _load

    return _load(path)
