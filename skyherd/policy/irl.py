"""Apprenticeship learning by inverse RL, projection method (Abbeel & Ng, ICML 2004, Sec. 3.1).

Reward model: R(s) = wᵀψ(s), ψ(s) ∈ [0, 1]^k. Feature expectations (seed Eq. 5)

    μ(π) = (1 − γ) · E[ Σ_t γ^t ψ(s_t) | π ]                       (k,)

(the (1 − γ) factor keeps μ in [0, 1]^k; it scales every μ alike, so the algorithm is unchanged).

Projection algorithm (the original; the seed's Algorithm 3 has a typo in its step 17):

    μ̄⁽⁰⁾ = μ⁽⁰⁾ = μ(π⁽⁰⁾),  w⁽¹⁾ = μ_E − μ⁽⁰⁾,  t⁽¹⁾ = ‖w⁽¹⁾‖₂
    for i = 1, 2, …:
        π⁽ⁱ⁾ = RL(R = w⁽ⁱ⁾ᵀψ),  μ⁽ⁱ⁾ = μ(π⁽ⁱ⁾)
        a = μ⁽ⁱ⁾ − μ̄⁽ⁱ⁻¹⁾,  b = μ_E − μ̄⁽ⁱ⁻¹⁾
        μ̄⁽ⁱ⁾ = μ̄⁽ⁱ⁻¹⁾ + (aᵀb / aᵀa) · a                              (orthogonal projection)
        w⁽ⁱ⁺¹⁾ = μ_E − μ̄⁽ⁱ⁾,  t⁽ⁱ⁺¹⁾ = ‖w⁽ⁱ⁺¹⁾‖₂;  stop when t ≤ ε

(The issue writes the same recursion with indices shifted by one: its μ⁽ⁱ⁻¹⁾, μ̄⁽ⁱ⁻²⁾ are our
μ⁽ⁱ⁾, μ̄⁽ⁱ⁻¹⁾.)

Final policy: `select_policy` returns the single learned policy whose μ is closest to μ_E
(the paper's "best single policy" option; this is what skyherd uses, because a flown policy must be
deterministic). `mixture_weights` also solves the paper's small QP
min ‖μ_E − Σ λ_i μ⁽ⁱ⁾‖₂ s.t. λ ≥ 0, Σλ = 1 and is reported beside it.

The RL solver and the μ estimator are passed in, so the same code runs with exact value iteration
on a gridworld (tests) and with DQN + Monte Carlo on the GroundAir task.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import minimize


@dataclass(frozen=True)
class IRLParams:
    """Projection-IRL hyper-parameters."""

    epsilon: float = 0.01  # stop when t = ‖μ_E − μ̄‖₂ ≤ ε
    max_iters: int = 8  # upper bound on RL calls (policies π⁽¹⁾ … π⁽ⁿ⁾)


@dataclass
class IRLIteration:
    """One row of the projection method's log."""

    i: int
    w: np.ndarray  # (k,) the reward weights the RL step was solved for
    mu: np.ndarray  # (k,) μ⁽ⁱ⁾ of the policy learned for w
    mu_bar: np.ndarray  # (k,) μ̄⁽ⁱ⁾ after projection
    t: float  # ‖μ_E − μ̄⁽ⁱ⁾‖₂ (margin after this iteration)
    dist: float  # ‖μ_E − μ⁽ⁱ⁾‖₂ of this single policy
    seconds: float = 0.0  # wall time of the RL step + μ estimate


@dataclass
class IRLResult:
    mu_expert: np.ndarray
    mu0: np.ndarray
    policies: list[Any]  # π⁽⁰⁾, π⁽¹⁾, …
    mus: list[np.ndarray]  # μ⁽⁰⁾, μ⁽¹⁾, …
    history: list[IRLIteration] = field(default_factory=list)
    converged: bool = False

    @property
    def t(self) -> float:
        return (
            self.history[-1].t if self.history else float(np.linalg.norm(self.mu_expert - self.mu0))
        )


def projection_step(mu_bar_prev: np.ndarray, mu_i: np.ndarray, mu_expert: np.ndarray) -> np.ndarray:
    """μ̄⁽ⁱ⁾ = μ̄⁽ⁱ⁻¹⁾ + (aᵀb / aᵀa) a with a = μ⁽ⁱ⁾ − μ̄⁽ⁱ⁻¹⁾, b = μ_E − μ̄⁽ⁱ⁻¹⁾."""
    a = mu_i - mu_bar_prev
    b = mu_expert - mu_bar_prev
    aa = float(a @ a)
    if aa <= 1e-18:  # the new policy adds nothing: μ̄ stays put
        return mu_bar_prev.copy()
    return mu_bar_prev + (float(a @ b) / aa) * a


def projection_irl(
    mu_expert: np.ndarray,
    policy0: Any,
    solve: Callable[[np.ndarray, int], Any],
    feature_expectations: Callable[[Any], np.ndarray],
    params: IRLParams = IRLParams(),
    on_iteration: Callable[[IRLIteration], None] | None = None,
    clock: Callable[[], float] | None = None,
) -> IRLResult:
    """Run the projection method.

    mu_expert: (k,) μ_E.  policy0: π⁽⁰⁾ (e.g. random).  solve(w, i) → policy optimal for R = wᵀψ.
    feature_expectations(policy) → (k,) μ.  clock: wall-time source for the log (time.perf_counter).
    """
    mu_expert = np.asarray(mu_expert, dtype=float)
    if not np.all(np.isfinite(mu_expert)):
        raise ValueError("μ_E contains NaN/inf")
    mu0 = np.asarray(feature_expectations(policy0), dtype=float)
    res = IRLResult(mu_expert=mu_expert, mu0=mu0, policies=[policy0], mus=[mu0])
    mu_bar = mu0.copy()
    w = mu_expert - mu_bar
    t = float(np.linalg.norm(w))
    if t <= params.epsilon:
        res.converged = True
        return res
    for i in range(1, params.max_iters + 1):
        t0 = clock() if clock else 0.0
        pi = solve(w, i)
        mu_i = np.asarray(feature_expectations(pi), dtype=float)
        mu_bar = projection_step(mu_bar, mu_i, mu_expert)
        w_next = mu_expert - mu_bar
        t = float(np.linalg.norm(w_next))
        it = IRLIteration(
            i=i,
            w=w.copy(),
            mu=mu_i,
            mu_bar=mu_bar.copy(),
            t=t,
            dist=float(np.linalg.norm(mu_expert - mu_i)),
            seconds=(clock() - t0) if clock else 0.0,
        )
        res.policies.append(pi)
        res.mus.append(mu_i)
        res.history.append(it)
        if on_iteration:
            on_iteration(it)
        w = w_next
        if t <= params.epsilon:
            res.converged = True
            break
    return res


def select_policy(result: IRLResult, include_initial: bool = False) -> int:
    """Index of the learned policy whose μ is closest to μ_E (the policy skyherd flies)."""
    start = 0 if include_initial or len(result.mus) == 1 else 1
    d = [np.linalg.norm(result.mu_expert - m) for m in result.mus[start:]]
    return start + int(np.argmin(d))


def mixture_weights(mus: list[np.ndarray], mu_expert: np.ndarray) -> np.ndarray:
    """λ = argmin ‖μ_E − Σ λ_i μ_i‖₂ s.t. λ ≥ 0, Σ λ = 1 (Abbeel & Ng's final QP). Shape (n,)."""
    M = np.asarray(mus, dtype=float)  # (n, k)
    n = M.shape[0]
    fun = lambda lam: float(np.sum((mu_expert - lam @ M) ** 2))  # noqa: E731
    jac = lambda lam: -2.0 * M @ (mu_expert - lam @ M)  # noqa: E731
    out = minimize(
        fun,
        np.full(n, 1.0 / n),
        jac=jac,
        bounds=[(0.0, 1.0)] * n,
        constraints=[{"type": "eq", "fun": lambda lam: lam.sum() - 1.0}],
        method="SLSQP",
    )
    lam = np.clip(out.x, 0.0, None)
    return lam / lam.sum()
