"""Learned UAV policies: the GroundAir task, DQN, projection IRL and Apprenticeship Bootstrapping.

Importing `policy` registers `skyherd/GroundAir-v0` with gymnasium (light: no torch import).
"""

from __future__ import annotations

import gymnasium as gym

ENV_ID = "skyherd/GroundAir-v0"

if ENV_ID not in gym.envs.registry:
    gym.register(id=ENV_ID, entry_point="policy.groundair.env:GroundAirEnv", max_episode_steps=None)
