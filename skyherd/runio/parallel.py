"""Many independent jobs in parallel, results as they finish: on Ray (a local instance or a
cluster) or a local process pool; a worker that dies loses only the job it was running, which
runs again.

    for job, result in map_unordered(fn, jobs, backend="auto", workers=2, ray_address=None):
        ...                                   # completion order; every job exactly once

`fn` is a module-level function of one picklable job, pure (same job → same result) so that a
re-run is the same run. Ray, local (address None): started on this machine on loopback only —
before `import ray` we set RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER=0, Ray's own switch that makes every
Ray server of a single-machine instance listen on 127.0.0.1 (without it Ray 2.60 rewrites
127.0.0.1 to the host's address and binds its gRPC servers to all interfaces) — with no
dashboard, shut down afterwards; a task whose worker dies is retried by Ray (`retries`). With
an address, Ray joins that cluster as configured there. The process pool (no Ray, or backend
"process"): a worker that dies breaks Python's pool, so the pool is rebuilt and the jobs that
had not finished are submitted again (each at most `retries` more times; then `JobLost`).
"""

from __future__ import annotations

import itertools
import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any

BACKENDS = ("auto", "ray", "process")
IN_FLIGHT_PER_WORKER = 4
"""Jobs handed out ahead per worker: every worker stays busy, and a campaign of 10^5-10^6 jobs
costs O(N) bookkeeping and memory (submitting all at once and waiting on every pending one per
result is O(N^2): hours of the parent's CPU at 10^5)."""


class JobLost(RuntimeError):
    """A job whose worker died more than `retries` times."""


def ray_available() -> bool:
    try:
        import importlib.util

        return importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):
        return False


def chosen_backend(backend: str, ray_address: str | None = None, say=print) -> str:
    """The backend a command runs on: `backend`, or for "auto" Ray when it is installed, else
    the process pool (said by `say`); ValueError if Ray is asked for (`backend` "ray" or a
    `ray_address`) and not installed."""
    if (backend == "ray" or ray_address) and not ray_available():
        raise ValueError("Ray is not installed: pip install -e '.[ray]' (or --backend process)")
    if backend != "auto":
        return backend
    if ray_available():
        return "ray"
    say("Ray is not installed: running on a local process pool (pip install -e '.[ray]')")
    return "process"


def import_ray_loopback():
    """Import ray so that a local instance listens on 127.0.0.1 only (see module doc)."""
    os.environ["RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"] = "0"
    import ray
    import ray._private.ray_constants as rc

    rc.ENABLE_RAY_CLUSTER = False  # in case ray was imported before the variable was set
    return ray


def map_unordered(fn: Callable[[Any], Any], jobs: Iterable[Any], backend: str = "auto",
                  workers: int = 2, ray_address: str | None = None, retries: int = 3,
                  say: Callable[[str], None] = print) -> Iterator[tuple[Any, Any]]:  # fmt: skip
    """Run `fn(job)` for every job; yield (job, result) in completion order.

    backend: "ray", "process" or "auto" (Ray when installed, else the process pool).
    workers: CPUs given to a local Ray instance / processes in the pool."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    jobs = list(jobs)
    use_ray = backend == "ray" or (backend == "auto" and ray_available())
    if use_ray and not ray_available():
        raise RuntimeError(
            "Ray is not installed: pip install 'skyherd[ray]', or use the process pool"
        )
    ray = start_ray(workers, ray_address, say) if use_ray else None
    if ray is not None:
        yield from _on_ray(ray, fn, jobs, workers, retries)
    else:
        yield from _on_pool(fn, jobs, workers, retries, say)


def start_ray(workers: int, address: str | None, say: Callable[[str], None] = print):
    """The ray module, initialised; None (and a message) if a local instance cannot start —
    on an overloaded machine Ray's start-up can time out — so the caller uses processes.
    A cluster address that cannot be joined is an error (the user asked for that cluster)."""
    if address is not None:
        import ray

        ray.init(address=address, log_to_driver=False)
        return ray
    ray = import_ray_loopback()
    try:
        ray.init(
            _node_ip_address="127.0.0.1", include_dashboard=False, num_cpus=workers,
            log_to_driver=False, configure_logging=False,
        )  # fmt: skip
    except Exception as e:  # noqa: BLE001 - Ray raises a bare Exception on a start-up timeout
        say(f"local Ray did not start ({e}); running on a local process pool instead")
        ray.shutdown()
        return None
    return ray


def _window(workers: int) -> int:
    """Jobs in flight at once: IN_FLIGHT_PER_WORKER per worker."""
    return IN_FLIGHT_PER_WORKER * max(1, workers)


def _on_ray(ray, fn, jobs, workers: int, retries: int):
    try:
        task = ray.remote(num_cpus=1, max_retries=retries)(fn)
        cpus = int(ray.cluster_resources().get("CPU", workers))  # a cluster's, or ours
        todo = iter(jobs)
        pending: dict = {}
        while True:
            for j in itertools.islice(todo, _window(cpus) - len(pending)):
                pending[task.remote(j)] = j
            if not pending:
                return
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                yield pending.pop(ref), ray.get(ref)
    finally:
        ray.shutdown()


def _on_pool(fn, jobs, workers: int, retries: int, say):
    todo = deque(range(len(jobs)))  # indices not yet submitted, in order
    tries = [0] * len(jobs)
    while todo:
        running: dict = {}  # future → index
        broken = False
        pool = ProcessPoolExecutor(max_workers=workers)
        try:
            while (todo or running) and not broken:
                while todo and len(running) < _window(workers) and not broken:
                    i = todo.popleft()
                    try:
                        running[pool.submit(fn, jobs[i])] = i
                    except BrokenProcessPool:
                        todo.appendleft(i)
                        broken = True
                done, _ = wait(running, return_when=FIRST_COMPLETED) if running else ((), ())
                for f in done:
                    try:
                        result = f.result()
                    except BrokenProcessPool:
                        broken = True
                        continue
                    yield jobs[running.pop(f)], result
        finally:  # a caller that stops (a signal, an error) waits for no job not yet begun
            pool.shutdown(wait=True, cancel_futures=True)
        if broken:  # a worker died: every job in flight then runs again on a new pool
            lost = sorted(running.values())
            for i in lost:
                tries[i] += 1
                if tries[i] > retries:
                    raise JobLost(f"job {jobs[i]!r}: its worker died {tries[i]} times")
            todo.extendleft(reversed(lost))
            say(f"a worker process died; {len(lost)} unfinished jobs run again on a new pool")
