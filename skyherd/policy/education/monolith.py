"""The comparison learner: one monolithic DQN taught the same lessons in the same order.

One Q-network over the raw observation (14,) and all 7 actions. Lesson i continues training the
network left by lesson i−1 (fresh replay buffer, ε schedule restarted) on lesson i's scenario
with lesson i's reward: the IRL reward weights the educated module of that lesson ended with
(`reward_w`), so both learners are asked the same thing; a lesson with warm_start = "demos" is
taught to it as to the module (DQfD: behaviour cloning on the lesson's demonstrations from the
current weights, then fine-tuning with them in every TD step; policy.education.dqfd); the composite lesson's reward is the
first projection-IRL step from the current network, w = μ_E − μ(π) (normalised). Nothing is
frozen, so later lessons may overwrite what earlier ones taught: what `skyherd educate` measures
by re-testing every earlier lesson after each one.

The loop is policy.dqn.train_dqn's (same TD step, buffer, ε schedule, target copies) with one
addition: it starts from given weights (policy.education.dqfd.run_dqn without demonstrations).
"""

from __future__ import annotations

import numpy as np

from skyherd.policy.dqn import DQNParams, MLPPolicy
from skyherd.policy.education.dqfd import run_dqn


def continue_dqn(env, params: DQNParams, init: MLPPolicy | None) -> MLPPolicy:
    """Train (from `init`'s weights if given) for params.total_steps env steps → greedy policy."""
    net = run_dqn(env, params, init)
    net.meta["learner"] = "monolithic_dqn"
    return net


def teach_monolith(cur, p, educated_results, composite_target, on_lesson=None):
    """The monolithic DQN on the educated run's schedule → list of LessonResult (retention).

    educated_results: teach()'s LessonResults (each skill lesson's `reward_w` and DQN steps);
    composite_target: (kind, vector) of the composite lesson (teach.composite_target).
    """
    import dataclasses
    import time

    from skyherd.policy.demos import rollout_stats
    from skyherd.policy.education.dqfd import behaviour_clone, finetune_params
    from skyherd.policy.education.teach import LessonResult, lesson_demos, test_policy
    from skyherd.policy.groundair.env import TASK_WEIGHTS, GroundAirEnv

    net, out, taught = None, [], []
    by_name = {r.lesson: r for r in educated_results}
    schedule = list(cur.lessons) + ([cur.composite] if cur.composite else [])
    for i, le in enumerate(schedule):
        t0 = time.process_time()
        if le is cur.composite:
            kind, vec = composite_target
            if kind == "measures":  # no ψ target: the environment's own task reward w_taskᵀψ
                vec = np.asarray(TASK_WEIGHTS, float)
            if kind == "mu":
                act = net if net is not None else (lambda o: 0)
                mu, _ = rollout_stats(act, le.scenario, p.mu_episodes, p.mu_seed, p.dqn.gamma)
                vec = vec - mu
            w = vec / max(float(np.linalg.norm(vec)), 1e-12)
            steps = p.dqn.total_steps * p.irl_iters
        else:
            w = np.asarray(by_name[le.name].detail["reward_w"], float)
            w = w / max(float(np.linalg.norm(w)), 1e-12)
            steps = max(by_name[le.name].dqn_steps, p.dqn.total_steps)
        dq = dataclasses.replace(p.dqn, total_steps=steps, seed=p.seed * 1000 + 900 + i)
        env = GroundAirEnv(le.scenario, reward_weights=w)
        if le is not cur.composite and le.warm_start == "demos":  # DQfD, as the module was
            d = lesson_demos(le, p)
            pairs = (d.obs.astype(np.float32), d.actions.astype(np.int64))
            net = behaviour_clone(*pairs, 7, p.dqn.hidden, p.dqfd, dq.seed, init=net)
            net = run_dqn(env, finetune_params(dq, p.dqfd), net, pairs, p.dqfd)
            net.meta["learner"] = "monolithic_dqn"
        else:
            net = continue_dqn(env, dq, net)
        taught.append(le)
        ret = {x.name: test_policy(net, x, p) for x in taught}
        passed = {x.name: all(c.ok(ret[x.name]) for c in x.passes) for x in taught}
        res = LessonResult(le.name, "monolith", "dqn", time.process_time() - t0, steps, ret,
                           passed, {"reward_w": w.tolist()})  # fmt: skip
        out.append(res)
        if on_lesson:
            on_lesson(res)
    return net, out
