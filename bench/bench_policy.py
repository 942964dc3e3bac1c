"""Benchmark of the learning stack: GroundAir env steps/s (fast path) and DQN updates/s.

Goal: >= 20,000 env steps/s on the fast path. Each rate is given per wall second and per CPU
second of this process (the machine is shared: the CPU rate is what one free core does).
Prints a table; --quick for a short run.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np  # noqa: E402


def _timed(fn, n):
    w, c = time.perf_counter(), time.process_time()
    fn()
    return n / (time.perf_counter() - w), n / max(time.process_time() - c, 1e-9)


def env_steps_per_s(n: int, scenario: str, act=None, pixels: bool = False) -> float:
    from skyherd.policy.groundair.env import GroundAirEnv

    env = GroundAirEnv(scenario, pixels=pixels)
    rng = np.random.default_rng(0)
    acts = rng.integers(0, 7, size=n)
    obs, _ = env.reset(seed=0)

    def loop():
        o = obs
        for i in range(n):
            o, _, term, trunc, _ = env.step(int(acts[i]) if act is None else act(o))
            if term or trunc:
                o, _ = env.reset()

    return _timed(loop, n)


def gym_make_steps_per_s(n: int) -> float:
    import gymnasium as gym

    from skyherd import policy

    env = gym.make(policy.ENV_ID)
    env.reset(seed=0)

    def loop():
        for i in range(n):
            _, _, term, trunc, _ = env.step(i % 7)
            if term or trunc:
                env.reset()

    return _timed(loop, n)


def dqn_updates_per_s(n: int) -> float:
    import torch

    from skyherd.policy.dqn import DQNParams, ReplayBuffer, build_qnet, td_update

    p = DQNParams()
    torch.set_num_threads(p.num_threads)
    torch.manual_seed(0)
    q, qt = build_qnet(14, 7, p.hidden), build_qnet(14, 7, p.hidden)
    opt = torch.optim.Adam(q.parameters(), lr=p.lr)
    buf = ReplayBuffer(10_000, 14)
    rng = np.random.default_rng(0)
    for _ in range(10_000):
        buf.add(rng.random(14), int(rng.integers(7)), float(rng.random()), rng.random(14), False)
    for _ in range(20):
        td_update(q, qt, opt, buf.sample(rng, p.batch_size), p.gamma, p.double, p.grad_clip)

    def loop():
        for _ in range(n):
            td_update(q, qt, opt, buf.sample(rng, p.batch_size), p.gamma, p.double, p.grad_clip)

    return _timed(loop, n)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="short run")
    args = ap.parse_args(argv)
    from skyherd.policy.dqn import load_policy
    from skyherd.runio.runfolder import markdown_table

    n = 20_000 if args.quick else 100_000
    rows = []
    f = lambda x: f"{x:,.0f}"  # noqa: E731
    for sc in ("composite", "lateral"):
        w, c = env_steps_per_s(n, sc)
        ok = "ok" if c >= 20_000 else "BELOW"
        rows.append([f"env steps/s, {sc}, random actions", f(w), f(c), "20,000", ok])
    w, c = env_steps_per_s(n // 20, "composite", pixels=True)
    rows.append(["env steps/s, pixels (OpenCV render + detector)", f(w), f(c), "-", "-"])
    w, c = gym_make_steps_per_s(n // 2)
    rows.append(["env steps/s via gym.make (checker wrappers)", f(w), f(c), "-", "-"])
    model = (
        Path(__file__).resolve().parents[1] / "skyherd" / "policy" / "models" / "groundair_ab.npz"
    )
    if model.exists():
        w, c = env_steps_per_s(n // 4, "composite", load_policy(model))
        rows.append(["env + learned policy (numpy MLP) steps/s", f(w), f(c), "-", "-"])
    w, c = dqn_updates_per_s(500 if args.quick else 3000)
    rows.append(["DQN updates/s (batch 64, MLP 64x64, 1 thread)", f(w), f(c), "-", "-"])
    print(markdown_table(["measure", "per wall s", "per CPU s", "goal", "status"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
