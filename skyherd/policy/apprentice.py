"""Projection IRL with DQN as the inner RL solver, on the GroundAir composite task.

Used by both learners: `skyherd train irl` (μ_E from composite demonstrations) and `skyherd train
ab` (μ_E^Primitive from sub-task demonstrations, policy.ab). Each IRL iteration trains a fresh
DQN on R = (w/‖w‖)ᵀψ (scaling w by a positive number does not change the optimal policy; unit
norm keeps the TD targets well scaled) and estimates μ(π) by Monte Carlo on fixed evaluation seeds.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skyherd.policy.demos import random_policy, rollout_stats
from skyherd.policy.dqn import DQNParams, MLPPolicy, train_dqn
from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.policy.irl import (
    IRLIteration,
    IRLParams,
    IRLResult,
    mixture_weights,
    projection_irl,
    select_policy,
)


@dataclass(frozen=True)
class ApprenticeParams:
    """Everything one apprenticeship run needs besides μ_E."""

    dqn: DQNParams = DQNParams()
    irl: IRLParams = IRLParams()
    mu_episodes: int = 20  # Monte-Carlo episodes per μ(π) estimate
    mu_seed: int = 50_000  # first environment seed of the μ estimates
    scenario: str = "composite"
    seed: int = 0  # run seed: offsets the DQN seeds of every iteration


@dataclass
class ApprenticeResult:
    irl: IRLResult
    chosen: int  # index into irl.policies of the flown policy
    policy: MLPPolicy
    mixture: np.ndarray  # QP weights λ over irl.policies (reported)
    seconds: float  # wall time of the whole run


def run_apprenticeship(
    mu_expert: np.ndarray,
    params: ApprenticeParams,
    on_iteration: Callable[[IRLIteration], None] | None = None,
    progress: bool = False,
) -> ApprenticeResult:
    t0 = time.perf_counter()
    gamma = params.dqn.gamma

    def mu_of(policy) -> np.ndarray:
        mu, _ = rollout_stats(policy, params.scenario, params.mu_episodes, params.mu_seed, gamma)
        return mu

    def solve(w: np.ndarray, i: int) -> MLPPolicy:
        wn = w / max(float(np.linalg.norm(w)), 1e-12)
        env = GroundAirEnv(params.scenario, reward_weights=wn)
        dqn = dataclasses.replace(params.dqn, seed=params.seed * 1000 + i)
        res = train_dqn(env, dqn, progress=progress, desc=f"IRL iter {i}")
        res.policy.meta["irl_w"] = wn.tolist()
        return res.policy

    pi0 = random_policy(seed=params.seed)
    irl = projection_irl(mu_expert, pi0, solve, mu_of, params.irl, on_iteration, time.perf_counter)
    chosen = select_policy(irl)
    lam = mixture_weights(irl.mus, irl.mu_expert)
    policy = irl.policies[chosen]
    if not isinstance(policy, MLPPolicy):  # IRL stopped at once: nothing learned (μ⁽⁰⁾ ≈ μ_E)
        raise RuntimeError(
            "projection IRL returned no learned policy (μ_E equals the random policy's)"
        )
    return ApprenticeResult(irl, chosen, policy, lam, time.perf_counter() - t0)
