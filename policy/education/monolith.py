"""The comparison learner: one monolithic DQN taught the same lessons in the same order.

One Q-network over the raw observation (14,) and all 7 actions. Lesson i continues training the
network left by lesson i−1 (fresh replay buffer, ε schedule restarted) on lesson i's scenario
with lesson i's reward: the IRL reward weights the educated module of that lesson ended with
(`reward_w`), so both learners are asked the same thing; the composite lesson's reward is the
first projection-IRL step from the current network, w = μ_E − μ(π) (normalised). Nothing is
frozen, so later lessons may overwrite what earlier ones taught: what `skyherd educate` measures
by re-testing every earlier lesson after each one.

The loop is policy.dqn.train_dqn's (same TD step, buffer, ε schedule, target copies) with one
addition: it starts from given weights.
"""

from __future__ import annotations

import numpy as np

from policy.dqn import DQNParams, MLPPolicy, ReplayBuffer, build_qnet, epsilon_at, td_update


def continue_dqn(env, params: DQNParams, init: MLPPolicy | None) -> MLPPolicy:
    """Train (from `init`'s weights if given) for params.total_steps env steps → greedy policy."""
    import torch

    torch.set_num_threads(params.num_threads)
    torch.manual_seed(params.seed)
    rng = np.random.default_rng(params.seed)
    obs_dim = int(np.prod(env.observation_space.shape))
    n_actions = int(env.action_space.n)
    q = build_qnet(obs_dim, n_actions, params.hidden)
    if init is not None:
        lin = [m for m in q if isinstance(m, torch.nn.Linear)]
        with torch.no_grad():
            for m, W, b in zip(lin, init.weights, init.biases):
                m.weight.copy_(torch.as_tensor(W, dtype=torch.float32))
                m.bias.copy_(torch.as_tensor(b, dtype=torch.float32))
    q_target = build_qnet(obs_dim, n_actions, params.hidden)
    q_target.load_state_dict(q.state_dict())
    opt = torch.optim.Adam(q.parameters(), lr=params.lr)
    buf = ReplayBuffer(min(params.buffer_size, params.total_steps), obs_dim)
    obs, _ = env.reset(seed=params.seed)
    for step in range(params.total_steps):
        if rng.random() < epsilon_at(params, step):
            a = int(rng.integers(n_actions))
        else:
            with torch.no_grad():
                a = int(q(torch.as_tensor(obs, dtype=torch.float32).unsqueeze(0)).argmax())
        obs2, r, term, trunc, _ = env.step(a)
        buf.add(obs, a, r, obs2, term)
        obs = obs2
        if term or trunc:
            obs, _ = env.reset()
        if step >= params.learning_starts and step % params.train_every == 0:
            batch = buf.sample(rng, params.batch_size)
            td_update(q, q_target, opt, batch, params.gamma, params.double, params.grad_clip)
        if step % params.target_update_every == 0:
            q_target.load_state_dict(q.state_dict())
    return MLPPolicy.from_torch(q, meta={"learner": "monolithic_dqn"})


def teach_monolith(cur, p, educated_results, composite_target, on_lesson=None):
    """The monolithic DQN on the educated run's schedule → list of LessonResult (retention).

    educated_results: teach()'s LessonResults (each skill lesson's `reward_w` and DQN steps);
    composite_target: (kind, vector) of the composite lesson (teach.composite_target).
    """
    import dataclasses
    import time

    from policy.demos import rollout_stats
    from policy.education.teach import LessonResult, test_policy
    from policy.groundair.env import GroundAirEnv

    net, out, taught = None, [], []
    by_name = {r.lesson: r for r in educated_results}
    schedule = list(cur.lessons) + ([cur.composite] if cur.composite else [])
    for i, le in enumerate(schedule):
        t0 = time.process_time()
        if le is cur.composite:
            kind, vec = composite_target
            if kind == "mu":
                act = net if net is not None else (lambda o: 0)
                mu, _ = rollout_stats(act, le.scenario, p.mu_episodes, p.mu_seed, p.dqn.gamma)
                vec = vec - mu
            w = vec / max(float(np.linalg.norm(vec)), 1e-12)
            steps = p.dqn.total_steps * p.irl_iters
        else:
            w = np.asarray(by_name[le.name].detail["reward_w"], float)
            steps = max(by_name[le.name].dqn_steps, p.dqn.total_steps)
        dq = dataclasses.replace(p.dqn, total_steps=steps, seed=p.seed * 1000 + 900 + i)
        net = continue_dqn(GroundAirEnv(le.scenario, reward_weights=w), dq, net)
        taught.append(le)
        ret = {x.name: test_policy(net, x, p) for x in taught}
        passed = {x.name: all(c.ok(ret[x.name]) for c in x.passes) for x in taught}
        res = LessonResult(le.name, "monolith", "dqn", time.process_time() - t0, steps, ret,
                           passed, {"reward_w": w.tolist()})  # fmt: skip
        out.append(res)
        if on_lesson:
            on_lesson(res)
    return net, out
