"""Many independent training runs in parallel: on Ray (local or a cluster) or a process pool.

A run is described by a frozen `RunSpec` (learner, K, N, seed, rules, budget, map) and done by
`run_one`, a pure function of its spec (same spec → same result, bit for bit), so it can run
in any worker. `run_all` yields `(spec, RunResult)` pairs as runs finish.

Where the runs go (Ray local on loopback only, a cluster, or a process pool) is
runio.parallel's.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from dataclasses import dataclass, field, replace

import numpy as np

from skyherd.policy.sql.envfile import EnvSpec, generate_env
from skyherd.policy.sql.params import Algorithm, RoiPretrain, Rules, SQLHyper
from skyherd.policy.sql.train import train
from skyherd.runio.parallel import map_unordered, ray_available

__all__ = ["RunResult", "RunSpec", "ray_available", "run_all", "run_one"]


@dataclass(frozen=True)
class RunSpec:
    """One training run."""

    algorithm: str
    n_agents: int
    share_every: int
    """N (SQL-SIE only; 0 for SQL and SQL-D)."""
    seed: int
    """Learner seed; also the map seed unless `env` is given."""
    rules: Rules
    hyper: SQLHyper = field(default_factory=SQLHyper)
    pretrain: RoiPretrain = field(default_factory=RoiPretrain)
    env: EnvSpec | None = None
    """A fixed map (from --env); None: `generate_env(n_agents, seed)`."""

    @property
    def key(self) -> str:
        n = f"_N{self.share_every}" if self.algorithm == "sql-sie" else ""
        return f"{self.rules.name}_{self.algorithm}_K{self.n_agents}{n}_seed{self.seed}"


@dataclass(frozen=True, eq=False)
class RunResult:
    """Per-episode arrays (E,) of one run, its map and where/how long it ran."""

    steps: np.ndarray
    success: np.ndarray
    reached: np.ndarray
    collisions: np.ndarray
    agent_steps: np.ndarray
    env: EnvSpec
    wall_s: float
    worker: str


def run_one(spec: RunSpec) -> RunResult:
    """Train one run from scratch (any process; no shared state)."""
    t0 = time.perf_counter()
    env = spec.env or generate_env(spec.n_agents, spec.seed)
    hyper = replace(spec.hyper, share_every=max(spec.share_every, 1))
    r = train(
        Algorithm(spec.algorithm), env.layout(), hyper, spec.seed, rules=spec.rules,
        pretrain=spec.pretrain,
    )  # fmt: skip
    m = r.metrics
    return RunResult(
        m.steps, m.success, m.reached, m.collisions, m.agent_steps, env,
        time.perf_counter() - t0, f"{socket.gethostname()}:{os.getpid()}",
    )  # fmt: skip


def run_all(
    specs: list[RunSpec],
    backend: str = "auto",
    workers: int = 2,
    ray_address: str | None = None,
) -> Iterator[tuple[RunSpec, RunResult]]:
    """Run every spec; yield (spec, result) in completion order (runio.parallel: Ray when
    installed or asked for, else a process pool; a dead worker's run runs again)."""
    yield from map_unordered(run_one, specs, backend, workers, ray_address)
