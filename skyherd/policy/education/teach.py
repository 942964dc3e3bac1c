"""Teaching a curriculum: one lesson at a time, earlier skills frozen, every lesson re-tested.

Lesson i (a skill lesson) trains module m_i on its scenario with only its actions and its input
concepts, from its demonstrations (method "irl": projection IRL, DQN as the inner solver, the
learned policy closest to μ_E in μ kept; policy.irl) or from a given reward (method "dqn").
With warm_start = "demos" the module is first cloned from its lesson's demonstrations (DQfD's
pre-training, policy.education.dqfd); that clone is IRL's π⁽⁰⁾ and competes in the final
choice, and every DQN solve starts from it with the demonstrations' margin loss J_E in each TD
step (DQfD's fine-tuning). The module is then frozen: later lessons never change its weights.

The composite lesson trains the arbiter only: an ordered rule list over the curriculum's
predicates (policy.education.modular.Arbiter), built greedily (Rivest's decision lists, learnt
by forward selection): start with the best single module as default; repeatedly insert the rule
"if p then m", at the place in the list, that most lowers the lesson's objective, stop when none
does; then drop every rule whose removal does not raise it. Objective on fixed episodes (common random numbers):
    ab      ‖μ_E^Primitive − μ(π)‖₂, μ_E^Primitive = policy.ab.combine of the skill lessons'
            demonstrations (Apprenticeship Bootstrapping: no composite demonstration)
    irl     ‖μ_E − μ(π)‖₂ with μ_E from composite demonstrations
    reward  −wᵀμ(π)
    measures  the task's own measures on the composite scenario's training episodes (seeds
            arbiter_seed+, never the test episodes): J = −all_in_view_frac + β·footprint_ratio,
            a weighted-sum scalarisation of the two (Marler & Arora 2004, Struct. Multidisc.
            Optim. 26:369), β and the episode count in EduParams.measures (MeasuresObjective)
plus, with the composite's retention_weight λ_R > 0, the replay of the skill lessons:
    + λ_R · mean_l ‖μ_E^l − μ_l(π)‖₂      (μ_l: the whole policy on lesson l's scenario)
so the arbiter is also asked to keep calling each module where its own lesson needs it.

After every lesson each earlier lesson is re-tested on its own scenario (retention): before the
composite lesson with its own module, after it with the whole modular policy. A monolithic DQN
(policy.education.monolith) is taught the same lessons in the same order for comparison.
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from skyherd.policy.demos import (
    Demonstration,
    ExpertParams,
    demo_feature_expectations,
    load_demo,
    record,
    rollout_stats,
    scripted_expert,
)
from skyherd.policy.dqn import DQNParams, train_dqn
from skyherd.policy.education.concepts import compile_concepts
from skyherd.policy.education.curriculum import CompositeLesson, Curriculum, Lesson
from skyherd.policy.education.dqfd import DQfDParams, behaviour_clone, finetune_params, run_dqn
from skyherd.policy.education.modular import Arbiter, ModularPolicy, SkillModule, features
from skyherd.policy.groundair.env import GroundAirEnv
from skyherd.policy.irl import IRLParams, projection_irl, select_policy


@dataclass(frozen=True)
class MeasuresObjective:
    """The arbiter objective of composite method "measures": the task's measures, scalarised.

    J(π) = −all_in_view_frac + footprint_weight · footprint_ratio on `episodes` training episodes
    of the composite scenario (seeds EduParams.arbiter_seed+). With footprint_weight = 0.01 one
    unit of footprint ratio (footprint / smallest circle around the UGVs) is worth 1 % of the
    episode in view: keeping the team in view comes first, a tighter view breaks near-ties.
    """

    episodes: int = 12  # training episodes per estimate (the ab search uses arbiter_episodes)
    footprint_weight: float = 0.01  # β
    footprint_if_never: float = 50.0  # footprint ratio counted when no step had all in view

    def describe(self) -> str:
        return (f"J = -all_in_view_frac + {self.footprint_weight:g} * footprint_ratio "
                f"on {self.episodes} composite training episodes")  # fmt: skip

    def __call__(self, metrics: dict[str, float]) -> float:
        fp = metrics["footprint_ratio"]
        fp = self.footprint_if_never if math.isnan(fp) else fp
        return -metrics["all_in_view_frac"] + self.footprint_weight * fp


@dataclass(frozen=True)
class EduParams:
    """Hyper-parameters of `skyherd educate` (saved in config.json)."""

    dqn: DQNParams = DQNParams(total_steps=6_000, hidden=(32, 32))  # per DQN solve
    dqfd: DQfDParams = DQfDParams()  # lessons with warm_start = "demos"
    irl_iters: int = 1  # projection-IRL iterations per skill lesson
    irl_epsilon: float = 0.01  # IRL stop: t ≤ ε
    mu_episodes: int = 10  # Monte-Carlo episodes per μ(π) estimate
    mu_seed: int = 50_000  # first env seed of the μ estimates
    demo_episodes: int = 20  # scripted demonstrations per lesson
    demo_seed: int = 1_000  # first env seed of the demonstrations
    demo_epsilon: float = 0.05  # demonstrator's random-action probability
    demo_lag: float = 0.05  # demonstrator's repeat-action probability
    arbiter_episodes: int = 6  # episodes per arbiter-objective estimate
    arbiter_seed: int = 60_000  # first env seed of the arbiter search
    measures: MeasuresObjective = MeasuresObjective()  # composite method "measures"
    replay_episodes: int = 3  # episodes per skill lesson replayed in the arbiter objective
    max_rules: int = 8  # longest rule list
    test_episodes: int = 10  # test episodes per lesson (retention)
    test_seed: int = 100_000  # first env seed of the lesson tests (never trained on)
    monolith: bool = True  # also teach a monolithic DQN the same lessons
    seed: int = 0  # run seed (offsets every DQN seed)


QUICK = EduParams(
    dqn=DQNParams(total_steps=400, learning_starts=100, hidden=(16,), target_update_every=100),
    dqfd=DQfDParams(bc_steps=200),
    measures=MeasuresObjective(episodes=2),
    replay_episodes=1,
    irl_iters=1,
    mu_episodes=2,
    demo_episodes=2,
    arbiter_episodes=2,
    max_rules=2,
    test_episodes=2,
)


def params_of(o) -> EduParams:
    """The hyper-parameters of `skyherd educate`'s options: any object with them as attributes
    (an argparse namespace; None: the default, QUICK's with `o.quick`); ValueError naming the
    option."""
    p = QUICK if o.quick else EduParams()
    over: dict[str, Any] = {}
    if o.dqn_steps is not None:
        if o.dqn_steps < 100:
            raise ValueError("--dqn-steps must be >= 100")
        over["dqn"] = dataclasses.replace(p.dqn, total_steps=o.dqn_steps)
    if o.irl_iters is not None:
        if o.irl_iters < 1:
            raise ValueError("--irl-iters must be >= 1")
        over["irl_iters"] = o.irl_iters
    if o.test_episodes is not None:
        if o.test_episodes < 1:
            raise ValueError("--test-episodes must be >= 1")
        over["test_episodes"] = o.test_episodes
    return dataclasses.replace(p, monolith=not o.no_monolith, **over)


@dataclass
class LessonResult:
    """What one lesson did and how every lesson taught so far scores after it."""

    lesson: str
    module: str
    method: str
    seconds: float
    dqn_steps: int
    retention: dict[str, dict[str, float]]  # lesson name → test metrics after this lesson
    passed: dict[str, bool]
    detail: dict[str, Any] = field(default_factory=dict)


def concept_features(cur: Curriculum) -> Callable[[np.ndarray], dict[str, float]]:
    """obs → every concept's feature (quantities by value, predicates 1/0; modular.features)."""
    values = compile_concepts(cur.concept_list())
    preds = [c for c in cur.concept_list() if c.kind == "predicate"]
    return lambda obs: features(values(obs), preds)


class ConceptEnv:
    """GroundAirEnv seen through a module: obs = its input concepts, actions = its actions."""

    def __init__(self, scenario: str, feats, inputs: tuple[str, ...], actions, reward_weights):
        self.env = GroundAirEnv(scenario, reward_weights=reward_weights)
        self.values, self.inputs, self.actions = feats, inputs, tuple(actions)
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (len(inputs),), np.float32)
        self.action_space = gym.spaces.Discrete(len(actions))

    def _x(self, obs) -> np.ndarray:
        v = self.values(obs)
        return np.array([v[n] for n in self.inputs], np.float32)

    def reset(self, seed=None, options=None):
        obs, info = self.env.reset(seed=seed)
        return self._x(obs), info

    def step(self, i):
        obs, r, term, trunc, info = self.env.step(self.actions[int(i)])
        return self._x(obs), r, term, trunc, info


def lesson_demos(lesson: Lesson | CompositeLesson, p: EduParams) -> Demonstration:
    """The lesson's demonstrations: its file, or the scripted expert on its scenario."""
    if lesson.demos != "scripted":
        return load_demo(lesson.demos)
    ex = scripted_expert(lesson.scenario, ExpertParams(epsilon=p.demo_epsilon, lag=p.demo_lag), 7)
    meta = {"expert": dataclasses.asdict(ex.p)}
    return record(lesson.scenario, ex, p.demo_episodes, p.demo_seed, "scripted", meta)


def as_obs_policy(module: SkillModule, feats) -> Callable[[np.ndarray], int]:
    return lambda obs: module.act(feats(obs))


def test_policy(act, lesson, p: EduParams) -> dict[str, float]:
    _, m = rollout_stats(act, lesson.scenario, p.test_episodes, p.test_seed, p.dqn.gamma)
    return m


# --------------------------------------------------------------------------- skill lessons
def teach_module(
    lesson: Lesson,
    cur: Curriculum,
    p: EduParams,
    demo: Demonstration | None,
    index: int,
    progress: bool = False,
) -> tuple[SkillModule, dict[str, Any]]:
    """Train lesson's module (irl: from `demo`; dqn: on lesson.reward; warm_start "demos":
    DQfD, behaviour cloning first). Returns it and a log."""
    values = concept_features(cur)
    gamma = p.dqn.gamma
    steps = 0
    warm = lesson.warm_start == "demos"
    pairs = module_pairs(lesson, demo, values) if warm else None
    bc = None
    if warm:
        seed = p.seed * 1000 + 100 * index
        bc = behaviour_clone(*pairs, len(lesson.actions), p.dqn.hidden, p.dqfd, seed)
        bc.meta.update({"irl_w": [], "module": lesson.module})

    def solve(w: np.ndarray, i: int) -> SkillModule:
        nonlocal steps
        wn = w / max(float(np.linalg.norm(w)), 1e-12)
        env = ConceptEnv(lesson.scenario, values, lesson.inputs, lesson.actions, wn)
        dq = dataclasses.replace(p.dqn, seed=p.seed * 1000 + 100 * index + i)
        if warm:  # DQfD fine-tuning: from the cloned weights, J_E on the demos in every step
            net = run_dqn(env, finetune_params(dq, p.dqfd), bc, pairs, p.dqfd)
        else:
            net = train_dqn(env, dq, progress=progress, desc=f"{lesson.name} dqn {i}").policy
        steps += dq.total_steps
        net.meta.update({"irl_w": wn.tolist(), "module": lesson.module})
        return SkillModule(lesson.module, lesson.name, lesson.inputs, lesson.actions, net)

    log: dict[str, Any] = {}
    if warm:
        mod0 = SkillModule(lesson.module, lesson.name, lesson.inputs, lesson.actions, bc)
        log.update(demo_pairs=len(pairs[1]), bc_agreement=agreement(mod0, pairs))
    if lesson.method == "dqn":
        mod = solve(np.asarray(lesson.reward, float), 1)
        log.update(dqn_steps=steps, reward_w=list(lesson.reward))
        if warm:
            log.update(dqfd_agreement=agreement(mod, pairs))
        return mod, log

    def mu_of(pol) -> np.ndarray:
        act = as_obs_policy(pol, values) if isinstance(pol, SkillModule) else pol
        return rollout_stats(act, lesson.scenario, p.mu_episodes, p.mu_seed, gamma)[0]

    rng = np.random.default_rng(p.seed)
    # π⁽⁰⁾: random, or (warm start) the cloned module — Abbeel & Ng allow any initial policy;
    # then it also competes in the final "closest μ" choice
    pi0 = mod0 if warm else (lambda obs: int(rng.choice(lesson.actions)))
    mu_e = demo_feature_expectations(demo, gamma)
    irl = projection_irl(
        mu_e, pi0, solve, mu_of, IRLParams(epsilon=p.irl_epsilon, max_iters=p.irl_iters)
    )
    chosen = select_policy(irl, include_initial=warm)
    mod = irl.policies[chosen]
    if not isinstance(mod, SkillModule):
        raise RuntimeError(f"lesson {lesson.name}: IRL learned no module (μ_E ≈ random's)")
    # the reward the lesson ended with (the monolith is taught it): the chosen policy's, or if
    # that is π⁽⁰⁾ the last one IRL solved for (μ_E itself if IRL stopped at once)
    w_end = mod.net.meta["irl_w"] or (irl.history[-1].w.tolist() if irl.history else mu_e.tolist())
    log.update(dqn_steps=steps, irl_t=[h.t for h in irl.history], chosen=chosen,
               irl_dist=[float(np.linalg.norm(mu_e - m)) for m in irl.mus],
               reward_w=w_end, mu_expert=mu_e.tolist())  # fmt: skip
    if warm:
        log.update(chosen_agreement=agreement(mod, pairs))
    return mod, log


def module_pairs(lesson: Lesson, demo: Demonstration, values) -> tuple[np.ndarray, np.ndarray]:
    """The demonstrations as the module sees them: (input concepts (N, k), action index (N,));
    rows whose action is not one of the module's are left out."""
    index = {a: i for i, a in enumerate(lesson.actions)}
    keep = [t for t, a in enumerate(demo.actions) if int(a) in index]
    x = np.array([[values(demo.obs[t])[n] for n in lesson.inputs] for t in keep], np.float32)
    a = np.array([index[int(demo.actions[t])] for t in keep], np.int64)
    return x.reshape(len(keep), len(lesson.inputs)), a


def agreement(mod: SkillModule, pairs: tuple[np.ndarray, np.ndarray]) -> float:
    """Fraction of demonstrated pairs whose action the module's greedy choice repeats."""
    x, a = pairs
    return float(np.mean(np.argmax(mod.net.q_values(x), axis=1) == a)) if len(a) else math.nan


# --------------------------------------------------------------------------- the arbiter
def composite_target(comp: CompositeLesson, cur: Curriculum, demos: dict, p: EduParams):
    """(kind, vector): ("mu", μ_E) for ab / irl, ("w", w) for reward, ("measures", [β])."""
    gamma = p.dqn.gamma
    if comp.method == "reward":
        return "w", np.asarray(comp.reward, float)
    if comp.method == "measures":
        return "measures", np.array([p.measures.footprint_weight])
    if comp.method == "irl":
        return "mu", demo_feature_expectations(lesson_demos(comp, p), gamma)
    by_scenario = {le.scenario: demos[le.name] for le in cur.lessons if le.name in demos}
    from skyherd.policy.ab import SUBTASKS, combine

    if all(s in by_scenario for s in SUBTASKS):
        return "mu", combine(by_scenario, comp.ab_rule, gamma)
    # lessons on other scenarios: the mean of their μ_E (AB's mean rule)
    mus = [demo_feature_expectations(d, gamma) for d in demos.values()]
    return "mu", np.mean(mus, axis=0)


def learn_arbiter(
    comp: CompositeLesson,
    policy_of: Callable[[Arbiter], ModularPolicy],
    target,
    p: EduParams,
    on_eval: Callable[[], None] | None = None,
    replay: list[tuple[str, np.ndarray]] = (),
) -> tuple[Arbiter, list[dict]]:
    """Greedy decision-list search (module docstring). Returns the arbiter and its search log.

    replay: (scenario, μ_E) of the skill lessons; with comp.retention_weight = λ_R > 0 the
    objective is J(π) + λ_R · mean_l ‖μ_E^l − μ_l(π)‖₂, μ_l on lesson l's scenario (a
    regulariser that keeps what the lessons taught: the arbiter must still call each module
    where its lesson needs it)."""
    kind, vec = target

    def objective(arb: Arbiter) -> float:
        pol = policy_of(arb)
        n = p.measures.episodes if kind == "measures" else p.arbiter_episodes
        mu, met = rollout_stats(pol, comp.scenario, n, p.arbiter_seed, p.dqn.gamma)
        if on_eval:
            on_eval()
        if kind == "measures":
            j = p.measures(met)
        else:
            j = float(np.linalg.norm(vec - mu)) if kind == "mu" else -float(vec @ mu)
        if comp.retention_weight > 0 and replay:
            ds = [np.linalg.norm(mu_l - rollout_stats(pol, sc, p.replay_episodes, p.arbiter_seed,
                                                      p.dqn.gamma)[0]) for sc, mu_l in replay]  # fmt: skip
            j += comp.retention_weight * float(np.mean(ds))
        return j

    log: list[dict] = []
    if kind == "measures":
        log.append({"step": "objective", "text": p.measures.describe()})
    scored = [(objective(Arbiter((), m)), m) for m in comp.modules]
    best, default = min(scored)
    log.append({"step": "default", "module": default, "objective": best})
    rules: list[tuple[str, str]] = []
    for _ in range(p.max_rules):
        used = {r[0] for r in rules}
        cands = [(i, (q, m)) for i in range(len(rules) + 1)
                 for q in comp.arbiter_inputs if q not in used for m in comp.modules]  # fmt: skip
        if not cands:
            break
        trial = [(objective(Arbiter(tuple(rules[:i] + [c] + rules[i:]), default)), i, c)
                 for i, c in cands]  # fmt: skip
        val, i, c = min(trial)
        if val >= best - 1e-6:
            break
        rules.insert(i, c)
        best = val
        log.append({"step": "add", "rule": list(c), "at": i, "objective": val})
    k = 0
    while k < len(rules):  # prune: keep a rule only if it helps
        val = objective(Arbiter(tuple(rules[:k] + rules[k + 1 :]), default))
        if val <= best + 1e-6:
            log.append({"step": "drop", "rule": list(rules[k]), "objective": val})
            rules.pop(k)
            best = min(best, val)
        else:
            k += 1
    return Arbiter(tuple(rules), default), log


# --------------------------------------------------------------------------- the whole course
def curriculum_meta(cur: Curriculum) -> dict[str, Any]:
    return {"name": cur.name, "version": cur.version, "sha256": cur.sha256, "path": cur.path}


def teach(
    cur: Curriculum,
    p: EduParams,
    on_lesson: Callable[[LessonResult], None] | None = None,
    tick: Callable[[str], None] | None = None,
    progress: bool = False,
) -> tuple[ModularPolicy, list[LessonResult]]:
    """Teach every lesson in order; returns the modular policy and one result per lesson."""
    values = concept_features(cur)
    modules: dict[str, SkillModule] = {}
    demos: dict[str, Demonstration] = {}
    results: list[LessonResult] = []
    taught: list[Lesson] = []
    for i, le in enumerate(cur.lessons):
        t0 = time.process_time()
        if le.method == "irl" or le.warm_start == "demos":
            demos[le.name] = lesson_demos(le, p)
        mod, detail = teach_module(le, cur, p, demos.get(le.name), i, progress)
        modules[le.module] = mod  # frozen from here on: nothing below trains it again
        taught.append(le)
        ret = {x.name: test_policy(as_obs_policy(modules[x.module], values), x, p) for x in taught}
        res = LessonResult(
            le.name, le.module, le.method, time.process_time() - t0, detail["dqn_steps"], ret,
            {x.name: all(c.ok(ret[x.name]) for c in x.passes) for x in taught}, detail,
        )  # fmt: skip
        results.append(res)
        if on_lesson:
            on_lesson(res)
    comp = cur.composite
    meta = {"curriculum": curriculum_meta(cur), "learner": "educated", "edu": p}
    if comp is None:  # no composite lesson: the last module flies alone
        last = cur.lessons[-1].module
        pol = ModularPolicy(cur.concept_list(), list(modules.values()), Arbiter((), last), meta)
        return pol, results
    t0 = time.process_time()
    mods = [modules[m] for m in comp.modules]

    def policy_of(arb: Arbiter) -> ModularPolicy:
        return ModularPolicy(cur.concept_list(), mods, arb, meta)

    target = composite_target(comp, cur, demos, p)
    replay = [(le.scenario, demo_feature_expectations(demos[le.name], p.dqn.gamma))
              for le in cur.lessons if le.module in comp.modules and le.name in demos]  # fmt: skip
    arb, log = learn_arbiter(
        comp, policy_of, target, p, (lambda: tick("arbiter")) if tick else None, replay
    )
    pol = policy_of(arb)
    pol.meta["composite_target"] = {"kind": target[0], "vector": target[1].tolist()}
    ret = {x.name: test_policy(pol, x, p) for x in list(cur.lessons) + [comp]}
    passed = {x.name: all(c.ok(ret[x.name]) for c in x.passes) for x in list(cur.lessons) + [comp]}
    res = LessonResult(comp.name, "arbiter", comp.method, time.process_time() - t0, 0, ret, passed,
                       {"arbiter": arb.describe(), "search": log})  # fmt: skip
    results.append(res)
    if on_lesson:
        on_lesson(res)
    return pol, results
