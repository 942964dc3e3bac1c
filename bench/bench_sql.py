"""Speed of the compiled SQL learners: episodes/s and agent-steps/s per learner and K.

Usage: .venv/bin/python bench/bench_sql.py [--quick] [--episodes E]
Each learner trains from scratch for E episodes (ε from 1, so the early, longest episodes
are included); the first call of each kernel compiles (or loads the cache) outside the timing.
"""

from __future__ import annotations

import argparse
import time

from policy.sql import Algorithm, GridParams, SQLHyper, build_layout, train
from runio.runfolder import markdown_table


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="500 episodes, K = 4 and 16")
    p.add_argument("--episodes", type=int, default=None, help="episodes per run (default 2000)")
    args = p.parse_args(argv)
    E = args.episodes or (500 if args.quick else 2000)
    Ks = (4, 16) if args.quick else (4, 9, 16)
    rows = []
    for K in Ks:
        lay = build_layout(GridParams(n_agents=K))
        for alg in Algorithm:
            train(alg, lay, SQLHyper(episodes=1, max_steps=5), seed=0)  # compile / load cache
            t0 = time.perf_counter()
            r = train(alg, lay, SQLHyper(episodes=E), seed=0)
            dt = time.perf_counter() - t0
            agent_steps = int(r.metrics.agent_steps.sum())
            rows.append(
                [
                    alg.value.upper(),
                    K,
                    E,
                    f"{dt:.2f}",
                    f"{E / dt:,.0f}",
                    f"{agent_steps / dt / 1e6:.1f}",
                    f"{10_000 * dt / E:.0f}",
                ]
            )
    print(
        markdown_table(
            [
                "learner",
                "K",
                "episodes",
                "wall s",
                "episodes/s",
                "agent-steps/s [M]",
                "10k episodes est. [s] (upper bound)",
            ],
            rows,
        )
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
