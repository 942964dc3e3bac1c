"""The SQL grid world one step at a time, PettingZoo parallel-API style.

The same rules as the compiled SQL kernel (`kernels.run_sql`): the move rule is the very
same function (`kernels.try_move`). Agents "agent_0" .. "agent_{K−1}" act in index order
within a step. Observation: the agent's own 1-based (x, y) cell.
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from skyherd.policy.sql import kernels
from skyherd.policy.sql.layout import Layout
from skyherd.policy.sql.params import SQLHyper


class FormationEnv:
    """reset() → (observations, infos); step(actions) → (obs, rewards, terminations,
    truncations, infos). The team bonus arrives with each agent's last reward."""

    metadata = {"name": "skyherd_sql_formation_v0", "is_parallelizable": True}

    def __init__(self, layout: Layout, hyper: SQLHyper | None = None):
        self.layout = layout
        self.hyper = hyper or SQLHyper()
        self.possible_agents = [f"agent_{i}" for i in range(layout.n_agents)]
        self.agents: list[str] = []
        M = layout.size
        self._obs_space = spaces.Box(low=1, high=M, shape=(2,), dtype=np.int64)
        self._act_space = spaces.Discrete(4)
        self._occ = np.zeros(layout.n_cells, np.int32)
        self._pos = layout.starts.astype(np.int64).copy()
        self._done = np.zeros(layout.n_agents, np.bool_)
        self._t = 0

    def observation_space(self, agent: str) -> spaces.Space:
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space:
        return self._act_space

    def _obs(self, i: int) -> np.ndarray:
        return np.array(self.layout.xy(int(self._pos[i])), dtype=np.int64)

    def reset(self, seed: int | None = None, options: dict | None = None):
        """Agents back on their start cells (the world has no randomness of its own)."""
        self.agents = list(self.possible_agents)
        self._pos[:] = self.layout.starts
        self._occ[:] = 0
        self._occ[self.layout.starts] = np.arange(1, self.layout.n_agents + 1)
        self._done[:] = False
        self._t = 0
        return {a: self._obs(i) for i, a in enumerate(self.possible_agents)}, {
            a: {} for a in self.possible_agents
        }

    def step(self, actions: dict[str, int]):
        """Move every active agent in index order; missing actions are a bad call."""
        if not self.agents:
            raise RuntimeError("step() after the episode ended: call reset()")
        lay, h = self.layout, self.hyper
        rewards = {a: 0.0 for a in self.agents}
        infos = {a: {} for a in self.agents}
        acting = list(self.agents)
        for name in acting:
            i = self.possible_agents.index(name)
            if name not in actions:
                raise ValueError(f"no action for {name}")
            a = int(actions[name])
            if not 0 <= a < 4:
                raise ValueError(f"action {a} for {name} is not in 0..3")
            s = int(self._pos[i])
            s2, code = kernels.try_move(
                s, a, lay.next_cell, lay.obstacle, self._occ, lay.roi_id, False
            )
            r = h.r_step
            if code == kernels.OBSTACLE:
                r = h.r_collision
            elif code == kernels.MOVED:
                self._occ[s] = 0
                self._occ[s2] = i + 1
                if lay.target_id[s2] >= 0:
                    r = h.r_goal
                    self._done[i] = True
            self._pos[i] = s2
            rewards[name] = r
            infos[name] = {"outcome": ("moved", "wall", "obstacle", "agent")[int(code)]}
        self._t += 1
        truncated = self._t >= h.max_steps
        last = bool(self._done.all()) or truncated
        terminations = {a: bool(self._done[self.possible_agents.index(a)]) for a in acting}
        truncations = {a: truncated and not terminations[a] for a in acting}
        if last:  # team bonus on every agent's last transition (agents done earlier too)
            for j, a in enumerate(self.possible_agents):
                if self._done.all():
                    b = h.bonus_all
                elif self._done[j]:
                    b = h.bonus_reached
                else:
                    b = h.bonus_missed
                rewards[a] = rewards.get(a, 0.0) + b
                infos.setdefault(a, {})["team_bonus"] = b
            self.agents = []
        else:
            self.agents = [a for a in acting if not terminations[a]]
        obs = {a: self._obs(self.possible_agents.index(a)) for a in rewards}
        return obs, rewards, terminations, truncations, infos
