"""A small deterministic gridworld with a linear reward wᵀψ(s): the exact test bed for IRL.

States are cells (row, col) of an H×W grid, index s = row·W + col. Actions: 0 stay, 1 north
(row − 1), 2 south, 3 east (col + 1), 4 west; moves into a wall leave the state unchanged.
ψ(s) ∈ {0,1}^k marks which of k regions the cell lies in. Everything is exact: value iteration
for the optimal policy, a linear solve for the discounted state distribution, so
μ(π) = (1 − γ) Σ_t γ^t E[ψ(s_t)] = d_πᵀ Ψ with d_π = (1 − γ)(I − γ P_πᵀ)⁻¹ p₀.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

MOVES = ((0, 0), (-1, 0), (1, 0), (0, 1), (0, -1))


@dataclass(frozen=True)
class GridWorld:
    """H×W grid, start cell `start`, discount γ, features Ψ (S, k)."""

    height: int
    width: int
    features: np.ndarray  # (S, k) ψ(s) per state
    start: int = 0
    gamma: float = 0.9

    @property
    def n_states(self) -> int:
        return self.height * self.width

    @property
    def n_actions(self) -> int:
        return len(MOVES)

    def next_state(self, s: int, a: int) -> int:
        r, c = divmod(s, self.width)
        dr, dc = MOVES[a]
        r2, c2 = r + dr, c + dc
        if 0 <= r2 < self.height and 0 <= c2 < self.width:
            return r2 * self.width + c2
        return s

    def transitions(self) -> np.ndarray:
        """(S, A) next-state table."""
        return np.array(
            [[self.next_state(s, a) for a in range(self.n_actions)] for s in range(self.n_states)]
        )

    def value_iteration(self, w: np.ndarray, tol: float = 1e-10) -> np.ndarray:
        """Optimal deterministic policy (S,) for R(s) = wᵀψ(s) (reward on the state entered from)."""
        R = self.features @ np.asarray(w, dtype=float)
        T = self.transitions()
        V = np.zeros(self.n_states)
        for _ in range(10_000):
            Q = R[:, None] + self.gamma * V[T]
            V2 = Q.max(axis=1)
            if np.max(np.abs(V2 - V)) < tol:
                V = V2
                break
            V = V2
        Q = R[:, None] + self.gamma * V[T]
        return np.argmax(Q + 1e-12 * (np.arange(self.n_actions) == 0), axis=1)  # ties → stay

    def feature_expectations(self, policy: np.ndarray) -> np.ndarray:
        """Exact μ(π) = d_πᵀ Ψ, shape (k,), for a deterministic policy (S,) of actions."""
        S = self.n_states
        T = self.transitions()
        P = np.zeros((S, S))
        P[np.arange(S), T[np.arange(S), np.asarray(policy)]] = 1.0
        p0 = np.zeros(S)
        p0[self.start] = 1.0
        d = (1.0 - self.gamma) * np.linalg.solve(np.eye(S) - self.gamma * P.T, p0)
        return d @ self.features


def region_features(height: int, width: int, cells_per_feature: list[list[int]]) -> np.ndarray:
    """Ψ (S, k): feature j is 1 on the cells listed in cells_per_feature[j]."""
    F = np.zeros((height * width, len(cells_per_feature)))
    for j, cells in enumerate(cells_per_feature):
        F[cells, j] = 1.0
    return F


class GridGoalEnv:
    """A gymnasium env on the same grid for testing DQN: reach the goal cell in the fewest moves.

    obs (2,) float32 = (row, col) / (size − 1); actions as MOVES; reward −0.05 per step and +1 on
    reaching the goal (terminates); truncation after `max_steps`. Optimal return from (0, 0):
    1 − 0.05·(2·size − 3) in 2·(size − 1) steps.
    """

    def __init__(self, size: int = 5, max_steps: int = 30):
        import gymnasium as gym

        self.size, self.max_steps = size, max_steps
        self.observation_space = gym.spaces.Box(0.0, 1.0, shape=(2,), dtype=np.float32)
        self.action_space = gym.spaces.Discrete(len(MOVES))
        self.r = self.c = self.k = 0

    def _obs(self) -> np.ndarray:
        return np.array([self.r, self.c], np.float32) / (self.size - 1)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        self.r = self.c = self.k = 0
        return self._obs(), {}

    def step(self, a: int):
        dr, dc = MOVES[int(a)]
        self.r = min(max(self.r + dr, 0), self.size - 1)
        self.c = min(max(self.c + dc, 0), self.size - 1)
        self.k += 1
        goal = self.r == self.size - 1 and self.c == self.size - 1
        return self._obs(), (1.0 if goal else -0.05), goal, self.k >= self.max_steps, {}
