"""A seeded torch MLP regressor (obs → scaled command) and its fit by behaviour cloning.

Network: Linear + ReLU per hidden layer, a linear output of 3 in units of the limits' scale
(policy.absdl.env.VelocityLimits.scale), loss = mean squared error on the scaled command,
Adam. `fit` is deterministic for a seed (torch's CPU kernels with one thread). The weights leave
as numpy arrays (W (out, in), b (out,)) for the numpy-only flown policy (policy.absdl.policy).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from skyherd.policy.dqn import build_qnet


def fit(
    x: np.ndarray,
    y: np.ndarray,
    hidden: tuple[int, ...],
    epochs: int,
    batch_size: int,
    lr: float,
    weight_decay: float,
    seed: int,
    num_threads: int = 1,
    on_epoch: Callable[[int, float], None] | None = None,
) -> tuple[list[np.ndarray], list[np.ndarray], list[float]]:
    """Fit x (N, obs_dim) → y (N, out) by MSE. Returns (weights, biases, loss per epoch)."""
    import torch

    torch.set_num_threads(num_threads)
    torch.manual_seed(seed)
    net = build_qnet(x.shape[1], y.shape[1], hidden)  # the same MLP as the DQN's
    opt = torch.optim.Adam(net.parameters(), lr=lr, weight_decay=weight_decay)
    xt = torch.from_numpy(np.asarray(x, np.float32))
    yt = torch.from_numpy(np.asarray(y, np.float32))
    g = torch.Generator().manual_seed(seed)
    losses = []
    n = len(xt)
    for ep in range(epochs):
        perm = torch.randperm(n, generator=g)
        total = 0.0
        for i in range(0, n, batch_size):
            idx = perm[i : i + batch_size]
            loss = torch.mean((net(xt[idx]) - yt[idx]) ** 2)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(idx)
        losses.append(total / n)
        if on_epoch is not None:
            on_epoch(ep, losses[-1])
    lin = [m for m in net if isinstance(m, torch.nn.Linear)]
    weights = [m.weight.detach().numpy().astype(np.float64) for m in lin]
    biases = [m.bias.detach().numpy().astype(np.float64) for m in lin]
    return weights, biases, losses


def forward(weights, biases, x: np.ndarray) -> np.ndarray:
    """The MLP in numpy: x (..., in) → (..., out)."""
    x = np.asarray(x, np.float64)
    for k, (W, b) in enumerate(zip(weights, biases)):
        x = x @ W.T + b
        if k < len(weights) - 1:
            x = np.maximum(x, 0.0)
    return x
