"""Learned UAV policies: the GroundAir task, DQN, projection IRL and Apprenticeship Bootstrapping.

`skyherd/GroundAir-v0` is registered with gymnasium by importing `policy` once gymnasium is
imported, and always by importing `policy.groundair.env` (the environment's module). The
commands that only fly (`skyherd sim`, `skyherd fly`) read the task's parameters from here and
do not import gymnasium at all (issue 31 item 3: lazy imports on every command's path).
"""

from __future__ import annotations

import sys

ENV_ID = "skyherd/GroundAir-v0"


def register() -> None:
    """Register ENV_ID with gymnasium (once)."""
    import gymnasium as gym

    if ENV_ID not in gym.envs.registry:
        gym.register(id=ENV_ID, entry_point="skyherd.policy.groundair.env:GroundAirEnv",
                     max_episode_steps=None)  # fmt: skip


if "gymnasium" in sys.modules:  # a gymnasium user: registered on import, as before
    register()


def load_policy(path):
    """Load a trained policy file → callable(obs (14,)) → action index (policy.groundair.params).

    Build obs with policy.groundair.env.make_observation; map the action to an offboard velocity
    setpoint with policy.groundair.params.action_velocity_ned. numpy only (no torch).
    """
    from skyherd.policy.dqn import load_policy as _load

    return _load(path)
