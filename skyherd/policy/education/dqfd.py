"""A skill module from its lesson's demonstrations: DQfD (Hester et al., AAAI 2018, §3).

Deep Q-learning from Demonstrations adds to DQN's TD loss a supervised large-margin loss on the
demonstrator's (state, action) pairs, so the greedy action of Q stays the demonstrator's where
the demonstrations say something and the TD loss shapes the rest:

    J_E(Q) = max_a [ Q(s, a) + l(a_E, a) ] − Q(s, a_E),   l(a_E, a) = 0 if a = a_E, else ℓ
    J(Q)   = J_DQ(Q) + λ_E · J_E(Q) + λ_L2 · ‖θ‖²

(J_DQ: the 1-step double-DQN loss of policy.dqn.td_update; the paper's n-step term J_n is left
out.) Two phases, as in the paper:

1. **Pre-training = behaviour cloning** (`behaviour_clone`): minimise λ_E·J_E + λ_L2·‖θ‖² on the
   demonstrations only. J_E is zero exactly when Q(s, a_E) beats every other action by ℓ, so its
   greedy policy is the demonstrator's (majority) action in every demonstrated state. No reward
   is needed: this is the warm start of a lesson with `warm_start = "demos"`, before IRL has
   chosen a reward.
2. **Fine-tuning** (`run_dqn`): DQN on the lesson's reward (IRL's w, or the lesson's stated one)
   from those weights, every TD step adding λ_E·J_E on a batch of demonstrations. Without
   demonstrations and from given weights (or fresh ones) it is plain DQN: the monolithic
   learner's continued training (policy.education.monolith).

A module reads predicates (1/0), so a module is a table over at most 2^k input patterns and a
few thousand demonstrated pairs cover the patterns the demonstrator visits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyherd.policy.dqn import DQNParams, MLPPolicy, build_qnet, load_weights, train_dqn


@dataclass(frozen=True)
class DQfDParams:
    """DQfD hyper-parameters (saved with the run; the paper's values where it gives them)."""

    margin: float = 0.8  # ℓ, the expert margin (paper: 0.8)
    lambda_e: float = 1.0  # λ_E, weight of J_E (paper: λ2 = 1.0)
    lambda_l2: float = 1e-5  # λ_L2 (paper: 1e-5)
    bc_steps: int = 1_500  # pre-training gradient steps (behaviour cloning)
    bc_lr: float = 1e-3  # Adam learning rate of the pre-training
    demo_batch: int = 64  # demonstrated pairs per J_E term
    finetune_eps: float = 0.05  # ε-greedy exploration while fine-tuning (constant: no random phase)
    finetune_learning_starts: int = 200  # env steps before the first fine-tuning update


def margin_loss(q, x, a_e, margin: float):
    """J_E over a batch: mean of max_a [Q(s,a) + l(a_E,a)] − Q(s,a_E) (torch tensors)."""
    import torch

    qs = q(x)
    lm = torch.full_like(qs, margin)
    lm.scatter_(1, a_e.unsqueeze(1), 0.0)
    return ((qs + lm).max(dim=1).values - qs.gather(1, a_e.unsqueeze(1)).squeeze(1)).mean()


def _l2(q):
    return sum((p**2).sum() for p in q.parameters())


def _demo_term(x: np.ndarray, a: np.ndarray, fd: DQfDParams, rng: np.random.Generator):
    """callable(q) → λ_E·J_E + λ_L2·‖θ‖² on a random batch of the demonstrated pairs."""
    import torch

    xt, at = torch.as_tensor(x, dtype=torch.float32), torch.as_tensor(a, dtype=torch.int64)

    def term(q):
        i = torch.as_tensor(rng.integers(0, len(at), size=fd.demo_batch))
        return fd.lambda_e * margin_loss(q, xt[i], at[i], fd.margin) + fd.lambda_l2 * _l2(q)

    return term


def behaviour_clone(
    x: np.ndarray, a: np.ndarray, n_actions: int, hidden: tuple[int, ...], fd: DQfDParams,
    seed: int, init: MLPPolicy | None = None,
) -> MLPPolicy:  # fmt: skip
    """DQfD pre-training on demonstrated pairs only (x (N, d) inputs, a (N,) action indices),
    from `init`'s weights if given (the monolith continues its network)."""
    import torch

    if len(a) == 0:
        raise ValueError("behaviour cloning needs at least one demonstrated pair")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    q = build_qnet(x.shape[1], n_actions, hidden)
    if init is not None:
        load_weights(q, init)
    opt = torch.optim.Adam(q.parameters(), lr=fd.bc_lr)
    term = _demo_term(x, a, fd, rng)
    for _ in range(fd.bc_steps):
        loss = term(q)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    return MLPPolicy.from_torch(q, meta={"learner": "dqfd_pretrain"})


def run_dqn(
    env,
    params: DQNParams,
    init: MLPPolicy | None = None,
    demos: tuple[np.ndarray, np.ndarray] | None = None,
    fd: DQfDParams = DQfDParams(),
) -> MLPPolicy:
    """DQN (policy.dqn.train_dqn: same TD step, buffer, ε schedule, target copies) for
    params.total_steps env steps, from `init`'s weights if given, with DQfD's λ_E·J_E (+ L2) on
    `demos` = (inputs, action indices) added to every TD step if given → the greedy policy."""
    extra = None
    if demos is not None:  # its own generator: the DQN's draws stay those of plain DQN
        extra = _demo_term(demos[0], demos[1], fd, np.random.default_rng(params.seed + 1))
    net = train_dqn(env, params, init=init, extra=extra).policy
    net.meta["learner"] = "dqfd" if demos is not None else "dqn"
    return net


def finetune_params(dq: DQNParams, fd: DQfDParams) -> DQNParams:
    """The DQN schedule of a warm-started solve: constant small ε, short warm-up."""
    import dataclasses

    return dataclasses.replace(
        dq, eps_start=fd.finetune_eps, eps_end=fd.finetune_eps,
        learning_starts=min(fd.finetune_learning_starts, dq.learning_starts),
    )  # fmt: skip
