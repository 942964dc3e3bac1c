"""The arbiter objective on the task's own measures (composite method "measures")."""

import dataclasses
import math

import pytest

from skyherd.policy.demos import rollout_stats
from skyherd.policy.education.curriculum import DEFAULT_CURRICULUM, CurriculumError, load_curriculum
from skyherd.policy.education.dqfd import DQfDParams, behaviour_clone
from skyherd.policy.education.modular import Arbiter, ModularPolicy, SkillModule
from skyherd.policy.education.teach import (
    QUICK,
    EduParams,
    MeasuresObjective,
    composite_target,
    concept_features,
    learn_arbiter,
    lesson_demos,
    module_pairs,
)

CUR = load_curriculum(DEFAULT_CURRICULUM)
# the lessons' own demonstrations and pre-training (20 episodes, 1,500 steps: 3-5 s per module)
CLONE = dataclasses.replace(QUICK, demo_episodes=EduParams().demo_episodes, dqfd=DQfDParams())


def test_measures_objective_is_the_stated_scalarisation():
    j = MeasuresObjective(episodes=12, footprint_weight=0.01)
    assert j({"all_in_view_frac": 0.9, "footprint_ratio": 10.0}) == pytest.approx(-0.8)
    # never all in view: the footprint counts as footprint_if_never, not as NaN (or 0)
    assert j({"all_in_view_frac": 0.0, "footprint_ratio": math.nan}) == pytest.approx(0.5)
    # in view first: 1 % more in view outweighs a footprint 0.5 larger
    assert j({"all_in_view_frac": 0.95, "footprint_ratio": 10.5}) < j(
        {"all_in_view_frac": 0.94, "footprint_ratio": 10.0}
    )
    assert "0.01 * footprint_ratio on 12 composite training episodes" in j.describe()


def _modules(lessons):
    values = concept_features(CUR)
    mods = {}
    for i, le in enumerate(lessons):
        pairs = module_pairs(le, lesson_demos(le, CLONE), values)
        net = behaviour_clone(*pairs, len(le.actions), (32, 32), CLONE.dqfd, seed=i)
        mods[le.module] = SkillModule(le.module, le.name, le.inputs, le.actions, net)
    return mods


@pytest.fixture(scope="module")
def pol_of():
    mods = _modules(CUR.lessons)
    return lambda arb: ModularPolicy(CUR.concept_list(), list(mods.values()), arb, {})


@pytest.mark.slow
def test_measures_see_the_guarded_descent(pol_of):
    """The three modules cloned from their lessons' demonstrations, 2 training episodes: the
    rule list the 3.1.0 search finds ("centre first, descend when too tight, climb when too
    wide") tightens the view with the team kept in view, and the measures objective ranks it above lateral alone, which ranks above the
    unguarded descent (which loses the team)."""
    obj, seed = MeasuresObjective(episodes=2), EduParams().arbiter_seed

    def measures(rules) -> dict[str, float]:
        pol = pol_of(Arbiter(tuple(rules), "lateral"))
        return rollout_stats(pol, "composite", obj.episodes, seed, 0.97)[1]

    alone = measures(())
    guarded = measures([("off_centre", "lateral"), ("too_tight", "descend"), ("too_wide", "climb")])
    unguarded = measures([("too_tight", "descend")])
    assert guarded["all_in_view_frac"] >= alone["all_in_view_frac"] - 0.02
    assert guarded["footprint_ratio"] < 0.8 * alone["footprint_ratio"]
    assert unguarded["all_in_view_frac"] < 0.5 * alone["all_in_view_frac"]
    assert obj(guarded) < obj(alone) < obj(unguarded)


@pytest.mark.slow
def test_measures_search_refuses_a_descent_that_loses_the_team(pol_of):
    """With only too_tight to route on, the search on the task's measures keeps lateral alone:
    descending tightens the footprint but loses the team (a footprint-only objective would take
    it). The objective is logged first."""
    p = dataclasses.replace(CLONE, measures=MeasuresObjective(episodes=2), max_rules=1)
    comp = dataclasses.replace(CUR.composite, method="measures", modules=("lateral", "descend"),
                               arbiter_inputs=("too_tight",))  # fmt: skip
    target = composite_target(comp, CUR, {}, p)
    assert target[0] == "measures"
    arb, log = learn_arbiter(comp, pol_of, target, p)
    assert log[0] == {"step": "objective", "text": p.measures.describe()}
    assert arb == Arbiter((), "lateral"), log
    footprint_only = MeasuresObjective(episodes=2, footprint_weight=1.0)
    p = dataclasses.replace(p, measures=footprint_only)
    arb, log = learn_arbiter(comp, pol_of, composite_target(comp, CUR, {}, p), p)
    assert "descend" in [m for _, m in arb.rules] + [arb.default], log


def test_curriculum_accepts_measures_and_refuses_unknown_methods(tmp_path):
    text = open(DEFAULT_CURRICULUM).read()
    old = 'method = "measures"'
    assert old in text
    f = tmp_path / "m.toml"
    f.write_text(text.replace(old, 'method = "ab"'))
    assert load_curriculum(f).composite.method == "ab"
    f.write_text(text.replace(old, 'method = "metrics"'))
    with pytest.raises(CurriculumError, match="measures"):
        load_curriculum(f)
