"""Deep Q-Network (Mnih et al., Nature 2015) with the Double-DQN target (van Hasselt et al., 2016).

Reads top to bottom: hyper-parameters → Q-network → replay buffer → one gradient step → the
training loop → the greedy policy and its file format.

TD target for a transition (s, a, r, s′, terminated):
    DQN:        y = r + γ (1 − d) max_a′ Q_target(s′, a′)
    Double-DQN: y = r + γ (1 − d) Q_target(s′, argmax_a′ Q_online(s′, a′))
loss = Huber(Q_online(s, a) − y). Truncation (time limit) is not termination: it bootstraps.

Policy file (`.npz`, loadable without torch): arrays W0, b0, W1, b1, … of the MLP (Linear + ReLU,
last layer linear) and `meta` (a JSON string: obs_dim, n_actions, hidden, the hyper-parameters,
anything the caller adds). `load_policy(path)` → callable(obs) → int action (greedy).
"""

from __future__ import annotations

import dataclasses
import io
import json
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.runio.runfolder import atomic_write_bytes, to_jsonable


@dataclass(frozen=True)
class DQNParams:
    """DQN hyper-parameters (saved with every run)."""

    total_steps: int = 20_000  # environment steps
    gamma: float = 0.97  # discount
    lr: float = 1e-3  # Adam learning rate
    batch_size: int = 64  # transitions per gradient step
    buffer_size: int = 50_000  # replay capacity [transitions]
    learning_starts: int = 1_000  # steps of pure exploration before learning
    train_every: int = 2  # environment steps per gradient step
    target_update_every: int = 500  # environment steps between hard target-network copies
    eps_start: float = 1.0  # ε-greedy exploration at the start
    eps_end: float = 0.05  # … and after `eps_fraction` of the budget
    eps_fraction: float = 0.4  # fraction of total_steps over which ε decays linearly
    hidden: tuple[int, ...] = (64, 64)  # MLP hidden layer widths
    double: bool = True  # Double-DQN target
    grad_clip: float = 10.0  # gradient-norm clip
    num_threads: int = 1  # torch intra-op threads (the machine is shared)
    seed: int = 0  # seeds torch, numpy and the environment


def epsilon_at(p: DQNParams, step: int) -> float:
    """Linear ε schedule."""
    frac = min(1.0, step / max(1.0, p.eps_fraction * p.total_steps))
    return p.eps_start + frac * (p.eps_end - p.eps_start)


def build_qnet(obs_dim: int, n_actions: int, hidden: tuple[int, ...]):
    import torch.nn as nn

    layers: list[nn.Module] = []
    d = obs_dim
    for h in hidden:
        layers += [nn.Linear(d, h), nn.ReLU()]
        d = h
    layers.append(nn.Linear(d, n_actions))
    return nn.Sequential(*layers)


class ReplayBuffer:
    """Ring buffer of transitions in preallocated numpy arrays."""

    def __init__(self, capacity: int, obs_dim: int):
        self.capacity = int(capacity)
        self.obs = np.zeros((capacity, obs_dim), np.float32)
        self.next_obs = np.zeros((capacity, obs_dim), np.float32)
        self.act = np.zeros(capacity, np.int64)
        self.rew = np.zeros(capacity, np.float32)
        self.done = np.zeros(capacity, np.float32)
        self.n = 0
        self.i = 0

    def add(self, o, a: int, r: float, o2, terminated: bool) -> None:
        i = self.i
        self.obs[i] = o
        self.act[i] = a
        self.rew[i] = r
        self.next_obs[i] = o2
        self.done[i] = float(terminated)
        self.i = (i + 1) % self.capacity
        self.n = min(self.n + 1, self.capacity)

    def sample(self, rng: np.random.Generator, batch: int):
        idx = rng.integers(0, self.n, size=batch)
        return self.obs[idx], self.act[idx], self.rew[idx], self.next_obs[idx], self.done[idx]

    def __len__(self) -> int:
        return self.n


def td_update(
    q, q_target, opt, batch, gamma: float, double: bool, grad_clip: float, extra=None
) -> float:
    """One gradient step on a batch (numpy arrays). Returns the loss.

    extra: optional callable(q) → a scalar torch loss added to the TD loss before the step
    (DQfD's supervised term, policy.education.dqfd)."""
    import torch
    import torch.nn.functional as F

    o, a, r, o2, d = (torch.from_numpy(x) for x in batch)
    with torch.no_grad():
        if double:
            a2 = q(o2).argmax(dim=1, keepdim=True)
            q_next = q_target(o2).gather(1, a2).squeeze(1)
        else:
            q_next = q_target(o2).max(dim=1).values
        y = r + gamma * (1.0 - d) * q_next
    q_sa = q(o).gather(1, a.unsqueeze(1)).squeeze(1)
    loss = F.smooth_l1_loss(q_sa, y)
    if extra is not None:
        loss = loss + extra(q)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    torch.nn.utils.clip_grad_norm_(q.parameters(), grad_clip)
    opt.step()
    return float(loss.item())


@dataclass
class DQNResult:
    policy: MLPPolicy
    episode_returns: list[float]  # return of each finished training episode
    episode_end_steps: list[int]  # env step at which it ended
    losses: list[float]  # mean loss per 1000 env steps
    seconds: float
    updates: int


def train_dqn(
    env,
    params: DQNParams,
    reward_fn: Callable[[np.ndarray, float, dict], float] | None = None,
    checkpoint: Path | None = None,
    checkpoint_every: int = 0,
    progress: bool = False,
    desc: str = "dqn",
    init: MLPPolicy | None = None,
    extra=None,
) -> DQNResult:
    """Train on a gymnasium env with Box obs and Discrete actions.

    reward_fn(obs_next, env_reward, info) → reward replaces the env's reward (IRL uses wᵀψ).
    checkpoint: path of a torch checkpoint written atomically every `checkpoint_every` steps.
    init: start from these weights (same shape) instead of fresh ones.
    extra: callable(q) → a torch loss added to every TD step (td_update's `extra`).
    """
    import torch

    torch.set_num_threads(params.num_threads)
    torch.manual_seed(params.seed)
    rng = np.random.default_rng(params.seed)
    obs_dim = int(np.prod(env.observation_space.shape))
    n_actions = int(env.action_space.n)
    q = build_qnet(obs_dim, n_actions, params.hidden)
    if init is not None:
        load_weights(q, init)
    q_target = build_qnet(obs_dim, n_actions, params.hidden)
    q_target.load_state_dict(q.state_dict())
    opt = torch.optim.Adam(q.parameters(), lr=params.lr)
    buf = ReplayBuffer(min(params.buffer_size, params.total_steps), obs_dim)

    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=params.total_steps, desc=desc, leave=False, mininterval=0.5)
    t0 = time.perf_counter()
    obs, _ = env.reset(seed=params.seed)
    ep_ret, returns, ends, losses, loss_acc, updates = 0.0, [], [], [], [], 0
    for step in range(params.total_steps):
        if rng.random() < epsilon_at(params, step):
            a = int(rng.integers(n_actions))
        else:
            with torch.no_grad():
                a = int(q(torch.as_tensor(obs, dtype=torch.float32).unsqueeze(0)).argmax())
        obs2, r, term, trunc, info = env.step(a)
        if reward_fn is not None:
            r = reward_fn(obs2, r, info)
        buf.add(obs, a, r, obs2, term)
        ep_ret += r
        obs = obs2
        if term or trunc:
            returns.append(ep_ret)
            ends.append(step + 1)
            ep_ret = 0.0
            obs, _ = env.reset()
        if step >= params.learning_starts and step % params.train_every == 0:
            batch = buf.sample(rng, params.batch_size)
            loss_acc.append(
                td_update(
                    q, q_target, opt, batch, params.gamma, params.double, params.grad_clip, extra
                )  # fmt: skip
            )
            updates += 1
        if step % params.target_update_every == 0:
            q_target.load_state_dict(q.state_dict())
        if (step + 1) % 1000 == 0:
            losses.append(float(np.mean(loss_acc)) if loss_acc else float("nan"))
            loss_acc = []
            if bar is not None:
                bar.update(1000)
                if returns:
                    bar.set_postfix(ret=f"{np.mean(returns[-10:]):.2f}")
        if checkpoint is not None and checkpoint_every and (step + 1) % checkpoint_every == 0:
            save_checkpoint(checkpoint, q, opt, step + 1, params)
    if bar is not None:
        bar.close()
    if checkpoint is not None:
        save_checkpoint(checkpoint, q, opt, params.total_steps, params)
    policy = MLPPolicy.from_torch(q, meta={"dqn": to_jsonable(params)})
    return DQNResult(policy, returns, ends, losses, time.perf_counter() - t0, updates)


def load_weights(q, init: MLPPolicy) -> None:
    """Copy an MLPPolicy's weights into a torch Q-network of the same shape."""
    import torch

    lin = [m for m in q if isinstance(m, torch.nn.Linear)]
    with torch.no_grad():
        for m, W, b in zip(lin, init.weights, init.biases):
            m.weight.copy_(torch.as_tensor(W, dtype=torch.float32))
            m.bias.copy_(torch.as_tensor(b, dtype=torch.float32))


def save_checkpoint(path: Path, q, opt, step: int, params: DQNParams) -> None:
    """torch checkpoint (network, optimiser, step, hyper-parameters), written atomically."""
    import torch

    bio = io.BytesIO()
    torch.save(
        {
            "q": q.state_dict(),
            "opt": opt.state_dict(),
            "step": step,
            "params": dataclasses.asdict(params),
        },
        bio,
    )
    atomic_write_bytes(Path(path), bio.getvalue())


class MLPPolicy:
    """Greedy policy of a ReLU MLP Q-network, evaluated in numpy (no torch needed).

    __call__(obs (obs_dim,)) → int action = argmax_a Q(obs, a).  q_values(obs (..., obs_dim)).
    explain(obs) → {module, action, reason, q_values, margin}: what the flight records.
    """

    def __init__(self, weights: list[np.ndarray], biases: list[np.ndarray], meta: dict[str, Any]):
        if len(weights) != len(biases) or not weights:
            raise ValueError("policy needs matching, non-empty weight and bias lists")
        self.weights = [np.asarray(w, np.float64) for w in weights]  # each (out, in)
        self.biases = [np.asarray(b, np.float64) for b in biases]
        self.meta = dict(meta)
        self.obs_dim = self.weights[0].shape[1]
        self.n_actions = self.weights[-1].shape[0]

    @classmethod
    def from_torch(cls, q, meta: dict[str, Any] | None = None) -> MLPPolicy:
        import torch.nn as nn

        lin = [m for m in q if isinstance(m, nn.Linear)]
        return cls(
            [m.weight.detach().cpu().numpy().copy() for m in lin],
            [m.bias.detach().cpu().numpy().copy() for m in lin],
            meta or {},
        )

    def q_values(self, obs: np.ndarray) -> np.ndarray:
        x = np.asarray(obs, np.float64)
        for k, (W, b) in enumerate(zip(self.weights, self.biases)):
            x = x @ W.T + b
            if k < len(self.weights) - 1:
                x = np.maximum(x, 0.0)
        return x

    def _checked(self, obs) -> np.ndarray:
        obs = np.asarray(obs, np.float64)
        if obs.shape != (self.obs_dim,) or not np.all(np.isfinite(obs)):
            raise ValueError(
                f"policy expects a finite obs of shape ({self.obs_dim},), got {obs.shape}"
            )
        return obs

    def __call__(self, obs: np.ndarray) -> int:
        return int(np.argmax(self.q_values(self._checked(obs))))

    def action_names(self) -> tuple[str, ...]:
        """The ground-air task's action names for a 7-action network, else a0, a1, …"""
        from skyherd.task.params import ACTION_NAMES

        if self.n_actions == len(ACTION_NAMES):
            return ACTION_NAMES
        return tuple(f"a{i}" for i in range(self.n_actions))

    def explain(self, obs: np.ndarray) -> dict[str, Any]:
        """Why the greedy action: every action's Q value and the margin over the runner-up
        (the same decision as `__call__`: the lowest index among equal values)."""
        q = self.q_values(self._checked(obs))
        names = self.action_names()
        order = np.argsort(-q, kind="stable")
        a = int(order[0])
        b = int(order[1]) if q.shape[0] > 1 else a
        margin = float(q[a] - q[b])
        return {
            "module": str(self.meta.get("learner", "policy")),
            "action": names[a],
            "reason": f"Q-network chose {names[a]} (Q {q[a]:.3f}; runner-up {names[b]} "
            f"{q[b]:.3f}, margin {margin:.3f})",
            "q_values": {n: round(float(v), 4) for n, v in zip(names, q)},
            "margin": round(margin, 4),
        }

    def save(self, path: Path) -> None:
        """Write the `.npz` policy file atomically."""
        arrays: dict[str, np.ndarray] = {}
        for k, (W, b) in enumerate(zip(self.weights, self.biases)):
            arrays[f"W{k}"] = W.astype(np.float32)
            arrays[f"b{k}"] = b.astype(np.float32)
        meta = {
            "format": "skyherd-mlp-policy/1",
            "obs_dim": self.obs_dim,
            "n_actions": self.n_actions,
        }
        meta.update(self.meta)
        arrays["meta"] = np.array(json.dumps(to_jsonable(meta)))
        bio = io.BytesIO()
        np.savez_compressed(bio, **arrays)
        atomic_write_bytes(Path(path), bio.getvalue())


class PolicyFileError(ValueError):
    """A policy file that is missing, truncated or not a skyherd policy."""


def load_policy(path: str | os.PathLike) -> MLPPolicy:
    """Load a `.npz` policy file → callable(obs) → action. Raises PolicyFileError on bad files.

    An educated modular policy (policy.education.modular) loads as a ModularPolicy: the same
    callable, plus `explain(obs)`. An ABS-DL policy (policy.absdl.policy) loads as an
    AbsdlPolicy: callable(obs) → a velocity command (3,), `continuous` True, `explain(obs)`.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"]))
            if meta.get("format") == "skyherd-modular-policy/1":  # modules + arbiter, explains
                from skyherd.policy.education.modular import from_arrays

                return from_arrays(z, meta)
            if meta.get("format") == "skyherd-absdl-policy/1":  # continuous, explains
                from skyherd.policy.absdl.policy import from_arrays as absdl_from_arrays

                return absdl_from_arrays(z, meta)
            n = sum(1 for k in z.files if k.startswith("W"))
            weights = [z[f"W{k}"] for k in range(n)]
            biases = [z[f"b{k}"] for k in range(n)]
    except FileNotFoundError as e:
        raise PolicyFileError(f"{path}: no such policy file") from e
    except Exception as e:  # zipfile.BadZipFile, KeyError, ValueError, json errors …
        raise PolicyFileError(
            f"{path}: not a readable skyherd policy file ({type(e).__name__}: {e})"
        ) from e
    if meta.get("format") != "skyherd-mlp-policy/1":
        raise PolicyFileError(f"{path}: unknown policy format {meta.get('format')!r}")
    for W, b in zip(weights, biases):
        if not (np.all(np.isfinite(W)) and np.all(np.isfinite(b))):
            raise PolicyFileError(f"{path}: policy weights contain NaN/inf")
    try:
        return MLPPolicy(weights, biases, meta)
    except ValueError as e:
        raise PolicyFileError(f"{path}: {e}") from e
