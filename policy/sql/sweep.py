"""Many independent training runs in parallel: on Ray (local or a cluster) or a process pool.

A run is described by a frozen `RunSpec` (learner, K, N, seed, rules, budget, map) and done by
`run_one`, a pure function of its spec (same spec → same result, bit for bit), so it can run
in any worker. `run_all` yields `(spec, RunResult)` pairs as runs finish.

Ray, local (address None): started on this machine on loopback only — before `import ray`
we set RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, Ray's own switch that makes every Ray server of
a single-machine instance listen on 127.0.0.1 (without it Ray 2.60 rewrites 127.0.0.1 to the
host's address and binds its gRPC servers to all interfaces) — with no dashboard, and shut
down afterwards. With an address, Ray joins that cluster as configured there.
Without Ray installed, or with backend "process", a local `ProcessPoolExecutor` does the same.
"""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field, replace

import numpy as np

from policy.sql.envfile import EnvSpec, generate_env
from policy.sql.params import Algorithm, RoiPretrain, Rules, SQLHyper
from policy.sql.train import train


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


def ray_available() -> bool:
    try:
        import importlib.util

        return importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        return False


def _import_ray_loopback():
    """Import ray so that a local instance listens on 127.0.0.1 only (see module doc)."""
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    import ray
    import ray._private.ray_constants as rc

    rc.ENABLE_RAY_CLUSTER = False  # in case ray was imported before the variable was set
    return ray


def run_all(
    specs: list[RunSpec],
    backend: str = "auto",
    workers: int = 2,
    ray_address: str | None = None,
) -> Iterator[tuple[RunSpec, RunResult]]:
    """Run every spec; yield (spec, result) in completion order.

    backend: "ray", "process" or "auto" (Ray when installed, else the process pool).
    workers: CPUs given to a local Ray instance / processes in the pool.
    """
    if backend not in ("auto", "ray", "process"):
        raise ValueError(f"backend must be auto, ray or process, got {backend!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    use_ray = backend == "ray" or (backend == "auto" and ray_available())
    if use_ray and not ray_available():
        raise RuntimeError(
            "Ray is not installed: pip install 'skyherd[ray]', or use the process pool"
        )
    ray = _start_ray(workers, ray_address) if use_ray else None
    if ray is not None:
        yield from _run_ray(ray, specs)
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futs = {pool.submit(run_one, s): s for s in specs}
            for f in as_completed(futs):
                yield futs[f], f.result()


def _start_ray(workers, address):
    """The ray module, initialised; None (and a message) if a local instance cannot start —
    on an overloaded machine Ray's start-up can time out — so the caller uses processes.
    A cluster address that cannot be joined is an error (the user asked for that cluster)."""
    if address is not None:
        import ray

        ray.init(address=address, log_to_driver=False)
        return ray
    ray = _import_ray_loopback()
    try:
        ray.init(
            _node_ip_address="127.0.0.1", include_dashboard=False, num_cpus=workers,
            log_to_driver=False, configure_logging=False,
        )  # fmt: skip
    except Exception as e:  # Ray raises a bare Exception on a start-up timeout
        print(f"local Ray did not start ({e}); running on a local process pool instead")
        ray.shutdown()
        return None
    return ray


def _run_ray(ray, specs):
    try:
        task = ray.remote(num_cpus=1)(run_one)
        pending = {task.remote(s): s for s in specs}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                yield pending.pop(ref), ray.get(ref)
    finally:
        ray.shutdown()
