"""Speed of the compiled SQL learners: episodes/s and agent-steps/s per learner, K and rule set,
against two baselines measured in the same run.

Usage: .venv/bin/python bench/bench_sql.py [--quick] [--episodes E]

- Each learner trains from scratch for E episodes (default 10,000 = one study run, so
  episodes/s is the study's rate; --quick: 2000, the early long episodes weigh more) on the
  generated map of seed 0, under the published and the intended rules.
- Baseline 1: the intended rules (the kernels before the rule switches existed had exactly
  these code paths); the table gives published / intended.
- Baseline 2: the same SQL rules stepped in Python (`FormationEnv` + a NumPy Q update), a few
  episodes with ε = 1; compared in agent-steps/s, the work unit both do.
The first call of each kernel compiles (or loads the cache) outside the timing.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skyherd.policy.sql import Algorithm, FormationEnv, SQLHyper, train
from skyherd.policy.sql.envfile import generate_env
from skyherd.policy.sql.params import Rules
from skyherd.runio.runfolder import markdown_table


def python_sql_agent_steps_per_s(layout, episodes: int = 3, max_steps: int = 1000) -> float:
    """Agent-steps/s of SQL (ε = 1) in plain Python on `FormationEnv`."""
    h = SQLHyper(max_steps=max_steps)
    env = FormationEnv(layout, h)
    rng = np.random.default_rng(0)
    q = np.zeros((layout.n_agents, layout.n_cells, 4))
    n = 0
    t0 = time.perf_counter()
    for _ in range(episodes):
        obs, _ = env.reset()
        while env.agents:
            acts = {a: int(rng.integers(4)) for a in env.agents}
            before = {a: layout.cell(*obs[a]) for a in env.agents}
            obs, rew, term, _, _ = env.step(acts)
            for a, r in rew.items():
                if a not in acts:
                    continue
                i = int(a.split("_")[1])
                s, s2 = before[a], layout.cell(*obs[a])
                tgt = r if term[a] else r + h.gamma * q[i, s2].max()
                q[i, s, acts[a]] += h.alpha * (tgt - q[i, s, acts[a]])
                n += 1
    return n / (time.perf_counter() - t0)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="2000 episodes, K = 9 only")
    p.add_argument("--episodes", type=int, default=None, help="episodes per run (10000)")
    args = p.parse_args(argv)
    E = args.episodes or (2000 if args.quick else 10_000)
    Ks = (9,) if args.quick else (9, 16)
    rows, rates = [], {}
    for K in Ks:
        lay = generate_env(K, 0).layout()
        for alg in Algorithm:
            for rname in ("published", "intended"):
                rules = Rules.named(rname)
                h = SQLHyper(episodes=E, share_every=1)
                train(alg, lay, SQLHyper(episodes=1, max_steps=5), 0, rules=rules)  # compile
                t0 = time.perf_counter()
                r = train(alg, lay, h, seed=0, rules=rules)
                dt = time.perf_counter() - t0
                rates[(K, alg, rname)] = (E / dt, r.metrics.agent_steps.sum() / dt)
            (ep_p, st_p), (ep_i, st_i) = rates[(K, alg, "published")], rates[(K, alg, "intended")]
            label = alg.value.upper() + (" N=1" if alg is Algorithm.SQL_SIE else "")
            rows.append(
                [label, K, E, f"{ep_p:,.0f}", f"{ep_i:,.0f}", f"{ep_p / ep_i:.2f}",
                 f"{st_p / 1e6:.1f}", f"{st_i / 1e6:.1f}"]
            )  # fmt: skip
    print(
        markdown_table(
            [
                "learner",
                "K",
                "episodes",
                "episodes/s published",
                "episodes/s intended",
                "ratio",
                "agent-steps/s published [M]",
                "agent-steps/s intended [M]",
            ],
            rows,
        )  # fmt: skip
    )
    lay = generate_env(9, 0).layout()
    py = python_sql_agent_steps_per_s(lay)
    kern = rates[(9, Algorithm.SQL, "intended")][1]
    print(
        f"\nbaseline, SQL K=9 in Python (FormationEnv, ε = 1): {py / 1e3:.0f} k agent-steps/s; "
        f"compiled kernel: {kern / 1e6:.1f} M agent-steps/s = {kern / py:,.0f}× faster"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
