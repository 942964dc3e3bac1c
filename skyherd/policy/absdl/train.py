"""ABS-DL training, top to bottom: demonstrations → one network per sub-task (behaviour cloning,
then DAgger rounds) → the fused policy; the same on composite demonstrations → the baseline.

Every demonstration and every DAgger roll-out flies through the shield when `params.shield`
(policy.absdl.shield): the networks learn the commands the safety net lets through. Episode
seeds: demonstrations of sub-task k use seed·10⁴ + 1000·k + i, DAgger round r adds 100·(r+1);
all stay below `params.eval_seed`, so evaluation episodes are unseen.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from skyherd.policy.absdl.demonstrator import SUBTASKS, Demonstrator
from skyherd.policy.absdl.demos import DataSet, collect, dagger, from_recording
from skyherd.policy.absdl.env import velocity_limits
from skyherd.policy.absdl.mlp import fit
from skyherd.policy.absdl.params import AbsdlParams
from skyherd.policy.absdl.policy import FUSED, SINGLE, AbsdlPolicy
from skyherd.policy.absdl.shield import ShieldStats
from skyherd.task.observation import OBS_DIM
from skyherd.task.params import TaskParams

NETWORKS: tuple[str, ...] = (*SUBTASKS, "composite")


@dataclass
class TrainResult:
    fused: AbsdlPolicy
    baseline: AbsdlPolicy
    losses: dict[str, list[list[float]]] = field(default_factory=dict)  # net → per fit
    samples: dict[str, int] = field(default_factory=dict)
    demo_shield: dict[str, ShieldStats] = field(default_factory=dict)  # net → demo stats


def _seeds(p: AbsdlParams, k: int, n: int, round_: int = -1) -> list[int]:
    base = p.seed * 10_000 + 1000 * k + (100 * (round_ + 1) if round_ >= 0 else 0)
    seeds = [base + i for i in range(n)]
    if seeds[-1] >= p.eval_seed:
        raise ValueError(f"training seeds reach {seeds[-1]} >= eval_seed {p.eval_seed}")
    return seeds


def work_units(p: AbsdlParams, recorded: dict | None = None) -> int:
    """Episodes + fits the progress bar counts."""
    recorded = recorded or {}
    per_net = p.demo_episodes + p.dagger_rounds * p.dagger_episodes + (1 + p.dagger_rounds)
    own = sum(per_net for n in NETWORKS if n not in recorded)
    return own + sum(d.n_episodes + 1 for d in recorded.values())


def train(
    p: AbsdlParams, tick: Callable[[str], None] | None = None, recorded: dict | None = None
) -> TrainResult:
    """Train the four networks; `tick(what)` after each episode and each fit.

    recorded: network name → a recorded demonstration (policy.demos.Demonstration of that
    scenario, e.g. from `skyherd teleop`) used instead of the scripted demonstrator; a recorded
    network gets no DAgger rounds (nobody to label the learner's states)."""
    recorded = recorded or {}
    tick = tick or (lambda what: None)
    np.random.seed(p.seed)
    limits = velocity_limits()
    scale = limits.scale
    task = TaskParams()
    meta = {
        "scale": scale.tolist(),
        "limits": dataclasses.asdict(limits),
        "gate_temperature": p.gate_temperature,
        "spread_target": task.spread_target,
        "params": dataclasses.asdict(p),
    }
    res_nets: dict[str, tuple[list, list]] = {}
    out = TrainResult(None, None)  # type: ignore[arg-type]
    for k, name in enumerate(NETWORKS):
        demo = Demonstrator(name, p.demonstrator(noisy=True), task, limits)
        if name in recorded:
            data = from_recording(recorded[name], p.shield, lambda name=name: tick(name))
            out.demo_shield[name] = data.stats
            out.losses[name] = []
            res_nets[name] = _fit(p, data, scale, k, out.losses[name])
            out.samples[name] = len(data)
            tick(name)
            continue
        data = collect(
            name, demo, _seeds(p, k, p.demo_episodes), p.shield, lambda name=name: tick(name)
        )
        out.demo_shield[name] = data.stats
        out.losses[name] = []
        W, B = _fit(p, data, scale, k, out.losses[name])
        tick(name)
        for r in range(p.dagger_rounds):
            learner = AbsdlPolicy({"composite": (W, B)}, {**meta, "kind": SINGLE})
            more = dagger(name, learner, demo, _seeds(p, k, p.dagger_episodes, r), p.shield,
                          lambda name=name: tick(name))  # fmt: skip
            data.obs += more.obs
            data.target += more.target
            W, B = _fit(p, data, scale, k, out.losses[name])
            tick(name)
        res_nets[name] = (W, B)
        out.samples[name] = len(data)
    out.fused = AbsdlPolicy({k: res_nets[k] for k in SUBTASKS}, {**meta, "kind": FUSED})
    out.baseline = AbsdlPolicy({"composite": res_nets["composite"]}, {**meta, "kind": SINGLE})
    return out


def _fit(p: AbsdlParams, data: DataSet, scale: np.ndarray, k: int, curves: list) -> tuple:
    x, y = data.arrays()
    if x.shape[1] != OBS_DIM:
        raise ValueError(f"observations have {x.shape[1]} entries, expected {OBS_DIM}")
    W, B, losses = fit(x, y / scale, p.hidden, p.epochs, p.batch_size, p.lr, p.weight_decay,
                       p.seed * 100 + k, p.num_threads)  # fmt: skip
    curves.append(losses)
    return W, B
