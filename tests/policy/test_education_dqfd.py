"""Skill modules from their lessons' demonstrations (DQfD): the margin loss, behaviour cloning
that reproduces the demonstrator's table, a warm-started lesson that keeps it, the descend
lesson's stated reward, the arbiter's replay of the skill lessons. Fixed seeds, small budgets."""

import collections
import dataclasses

import numpy as np
import pytest

from skyherd.policy.demos import rollout_stats
from skyherd.policy.dqn import DQNParams
from skyherd.policy.education.curriculum import DEFAULT_CURRICULUM, load_curriculum
from skyherd.policy.education.dqfd import DQfDParams, behaviour_clone, margin_loss, run_dqn
from skyherd.policy.education.modular import Arbiter, ModularPolicy, SkillModule
from skyherd.policy.education.monolith import continue_dqn
from skyherd.policy.education.teach import (
    QUICK,
    ConceptEnv,
    agreement,
    concept_features,
    learn_arbiter,
    lesson_demos,
    module_pairs,
    teach_module,
)

CUR = load_curriculum(DEFAULT_CURRICULUM)
SMALL = dataclasses.replace(QUICK, demo_episodes=4, dqfd=DQfDParams(bc_steps=400))


def test_margin_loss_is_dqfds_j_e():
    import torch

    q = lambda x: x  # noqa: E731  Q(s, ·) given directly
    x = torch.tensor([[1.0, 0.0], [0.0, 0.5], [0.3, 0.2]])
    a = torch.tensor([0, 0, 1])
    # row 0: expert leads by 1.0 ≥ ℓ → 0; row 1: 0.5 + 0.8 − 0 = 1.3; row 2: 0.3 + 0.8 − 0.2 = 0.9
    assert float(margin_loss(q, x, a, 0.8)) == pytest.approx((0.0 + 1.3 + 0.9) / 3)


def _majority(pairs):
    cnt = collections.defaultdict(collections.Counter)
    for x, a in zip(*pairs):
        cnt[tuple(x.tolist())][int(a)] += 1
    return {k: c.most_common(1)[0][0] for k, c in cnt.items() if sum(c.values()) >= 10}


def test_behaviour_cloning_reproduces_the_demonstrators_table():
    """Pre-training alone: the greedy action is the demonstrations' majority action in every
    input pattern demonstrated ≥ 10 times (the demonstrator errs 10 % of the time)."""
    values = concept_features(CUR)
    le = CUR.lesson("lateral")
    pairs = module_pairs(le, lesson_demos(le, SMALL), values)
    assert len(pairs[1]) == 4 * 120 and pairs[0].shape == (480, len(le.inputs))
    net = behaviour_clone(*pairs, len(le.actions), (16,), SMALL.dqfd, seed=0)
    mod = SkillModule(le.module, le.name, le.inputs, le.actions, net)
    table = _majority(pairs)
    assert len(table) >= 5
    for pattern, a in table.items():
        assert mod.act_index(np.array(pattern)) == a, pattern
    assert agreement(mod, pairs) >= 0.9
    # an untrained network of the same shape does not (the test can fail)
    blank = behaviour_clone(
        *pairs, len(le.actions), (16,), dataclasses.replace(SMALL.dqfd, bc_steps=0), 0
    )
    assert agreement(SkillModule(le.module, le.name, le.inputs, le.actions, blank), pairs) < 0.9


def test_warm_started_irl_lesson_keeps_the_demonstrators_skill():
    """climb with warm_start = "demos": after IRL (DQfD fine-tuning) the module still repeats the
    demonstrations and passes its lesson on unseen test episodes."""
    le = CUR.lesson("climb")
    assert le.warm_start == "demos"
    mod, log = teach_module(le, CUR, SMALL, lesson_demos(le, SMALL), 1)
    assert log["bc_agreement"] >= 0.9 and log["chosen_agreement"] >= 0.9
    assert len(log["irl_dist"]) == 2 and log["reward_w"]  # π⁽⁰⁾ (cloned) and π⁽¹⁾
    values = concept_features(CUR)
    act = lambda o: mod.act(values(o))  # noqa: E731
    m = rollout_stats(act, le.scenario, 3, SMALL.test_seed, 0.97)[1]
    assert all(c.ok(m) for c in le.passes), m


def test_descend_reward_prefers_the_demonstrator_where_its_features_do_not():
    """Why descend learns from a stated reward: in ψ the demonstrator and a hovering UAV are
    nearly the same (IRL has nothing to separate), but the lesson's reward ranks them."""
    le = CUR.lesson("descend")
    assert le.method == "dqn" and le.warm_start == "demos"
    f = concept_features(CUR)

    def table(o):
        v = f(o)
        return 6 if v["too_tight"] and not (v["someone_out"] or v["near_floor"]) else 0

    mu_t, m_t = rollout_stats(table, "descend", 4, 50_000, 0.97)
    mu_h, m_h = rollout_stats(lambda o: 0, "descend", 4, 50_000, 0.97)
    assert np.linalg.norm(mu_t - mu_h) < 0.1  # features: almost the same
    assert m_t["footprint_ratio"] < 0.6 * m_h["footprint_ratio"]  # flights: not at all
    w = np.asarray(le.reward)
    assert w @ mu_t > w @ mu_h + 0.02


def test_run_dqn_without_demonstrations_is_the_monoliths_dqn():
    le = CUR.lesson("descend")
    env = lambda: ConceptEnv(le.scenario, concept_features(CUR), le.inputs, le.actions, le.reward)  # noqa: E731
    dq = DQNParams(total_steps=300, learning_starts=100, hidden=(8,), seed=3)
    a, b = run_dqn(env(), dq), continue_dqn(env(), dq, None)
    assert all(np.array_equal(x, y) for x, y in zip(a.weights, b.weights))


def test_arbiter_replay_keeps_a_module_the_composite_alone_drops():
    """A composite objective that a lateral-only arbiter satisfies best, and the climb lesson's
    replay: with retention_weight the search keeps a rule that calls climb."""
    values = concept_features(CUR)
    mods = {}
    for i, le in enumerate(CUR.lessons[:2]):
        pairs = module_pairs(le, lesson_demos(le, SMALL), values)
        net = behaviour_clone(*pairs, len(le.actions), (16,), SMALL.dqfd, seed=i)
        mods[le.module] = SkillModule(le.module, le.name, le.inputs, le.actions, net)
    pol_of = lambda arb: ModularPolicy(CUR.concept_list(), list(mods.values()), arb, {})  # noqa: E731
    p = dataclasses.replace(SMALL, arbiter_episodes=1, replay_episodes=1, max_rules=1)
    lat = rollout_stats(pol_of(Arbiter((), "lateral")), "composite", 1, p.arbiter_seed, 0.97)[0]
    climb_mu = rollout_stats(pol_of(Arbiter((("too_wide", "climb"),), "lateral")), "climb", 1,
                             p.arbiter_seed, 0.97)[0]  # fmt: skip
    comp = dataclasses.replace(CUR.composite, modules=("lateral", "climb"),
                               arbiter_inputs=("too_wide", "team_east"))  # fmt: skip
    alone, _ = learn_arbiter(comp, pol_of, ("mu", lat), p)
    assert alone == Arbiter((), "lateral")  # the composite target is lateral-only's own μ
    kept, log = learn_arbiter(dataclasses.replace(comp, retention_weight=1.0), pol_of,
                              ("mu", lat), p, replay=[("climb", climb_mu)])  # fmt: skip
    assert "climb" in [m for _, m in kept.rules] + [kept.default], log
