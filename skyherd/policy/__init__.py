"""Learned UAV policies: the GroundAir task, DQN, projection IRL and Apprenticeship Bootstrapping.

The gymnasium task `skyherd/GroundAir-v0`, from anywhere:

    import gymnasium as gym
    env = gym.make("skyherd.policy:skyherd/GroundAir-v0", scenario="composite")

Importing `skyherd.policy` imports neither gymnasium nor torch (the companion flies a policy
with numpy only): it registers the task when gymnasium is already imported (as in the
`module:id` form above), and `policy.groundair.env` registers it on its own import.
"""

from __future__ import annotations

import sys

ENV_ID = "skyherd/GroundAir-v0"


def register() -> None:
    """Register `skyherd/GroundAir-v0` with gymnasium (idempotent)."""
    import gymnasium as gym

    if ENV_ID not in gym.envs.registry:
        gym.register(
            id=ENV_ID,
            entry_point="skyherd.policy.groundair.env:GroundAirEnv",
            max_episode_steps=None,
        )


if "gymnasium" in sys.modules:
    register()


def load_policy(path):
    """Load a trained policy file → callable(obs (14,)) → action index (task.params).

    Build obs with task.observation.make_observation; map the action to an offboard velocity
    setpoint with task.params.action_velocity_ned. numpy only (no torch).
    """
    from skyherd.policy.dqn import load_policy as _load

    return _load(path)
