"""policy.irl_experiment without the command line: parameters, μ_E per learner, the runs (in
process and on a pool), the references and the best run, on tiny budgets."""

import dataclasses
import json

import numpy as np
import pytest

from skyherd.policy import irl_experiment as X
from skyherd.policy.ab import combine
from skyherd.policy.apprentice import ApprenticeParams
from skyherd.policy.demos import demo_feature_expectations
from skyherd.policy.dqn import DQNParams, MLPPolicy
from skyherd.policy.irl import IRLParams

TINY = ApprenticeParams(dqn=DQNParams(total_steps=300), irl=IRLParams(max_iters=1), mu_episodes=1)


def test_parameters_are_checked_and_name_the_learners():
    with pytest.raises(ValueError, match="learner"):
        X.ExperimentParams(learner="bc")
    with pytest.raises(ValueError, match="median"):
        X.ExperimentParams(learner="ab", rules=("median",))
    with pytest.raises(ValueError, match="rules"):
        X.ExperimentParams(learner="irl", rules=("mean",))
    with pytest.raises(ValueError, match="rules"):
        X.ExperimentParams(learner="ab")
    irl = X.ExperimentParams()
    assert irl.learners == ["irl"] and irl.main_learner == "irl"
    assert X.needed_scenarios(irl) == ["composite"]
    ab = X.ExperimentParams(learner="ab", rules=("mean", "var_weighted"))
    assert ab.learners == ["irl", "ab_mean", "ab_var_weighted"] and ab.main_learner == "ab_mean"
    assert X.needed_scenarios(ab) == ["lateral", "climb", "descend", "composite"]
    alone = X.ExperimentParams(learner="ab", rules=("mean",), with_irl=False)
    assert alone.learners == ["ab_mean"] and "composite" not in X.needed_scenarios(alone)
    assert ab.gamma == ab.apprentice.dqn.gamma == 0.97


def test_expert_feature_expectations_follow_the_demonstrations():
    p = X.ExperimentParams(learner="ab", rules=("mean", "per_feature"), demo_episodes=1)
    demos = {sc: X.scripted_demonstration(sc, p) for sc in X.needed_scenarios(p)}
    assert demos["climb"].meta["demonstrator"] == "scripted"
    assert demos["climb"].meta["expert"]["epsilon"] == 0.05  # the demonstrator's imperfection
    again = X.scripted_demonstration("climb", p)
    np.testing.assert_array_equal(again.actions, demos["climb"].actions)  # seeded
    mu = X.expert_feature_expectations(p, demos)
    assert list(mu) == ["irl", "ab_mean", "ab_per_feature"]
    np.testing.assert_array_equal(mu["irl"], demo_feature_expectations(demos["composite"], 0.97))
    subs = [demo_feature_expectations(demos[s], 0.97) for s in ("lateral", "climb", "descend")]
    np.testing.assert_allclose(mu["ab_mean"], np.mean(subs, axis=0), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(mu["ab_per_feature"], combine(demos, "per_feature", 0.97))
    jobs = X.jobs(dataclasses.replace(p, seeds=2, seed=4), mu)
    assert [(j.learner, j.seed) for j in jobs] == [
        ("irl", 4), ("ab_mean", 4), ("ab_per_feature", 4),
        ("irl", 5), ("ab_mean", 5), ("ab_per_feature", 5),
    ]  # fmt: skip


def _tiny_experiment():
    p = X.ExperimentParams(learner="ab", rules=("mean",), seeds=1, seed=2, apprentice=TINY,
                           demo_episodes=1, eval_episodes=1)  # fmt: skip
    demos = {sc: X.scripted_demonstration(sc, p) for sc in X.needed_scenarios(p)}
    return p, X.expert_feature_expectations(p, demos)


def test_runs_in_job_order_with_their_facts_rows_and_policy():
    p, mu = _tiny_experiment()
    ticks, finished = [], []
    runs = X.run_experiment(p, mu, 1, lambda *a: ticks.append(a),
                            lambda r, done: finished.append((r.learner, len(done))))  # fmt: skip
    assert [(r.learner, r.seed) for r in runs] == [("irl", 2), ("ab_mean", 2)]
    assert [t[:2] for t in ticks] == [("irl", 2), ("ab_mean", 2)]  # one IRL iteration each
    assert finished == [("irl", 1), ("ab_mean", 2)]
    r = runs[0]
    # the first reward weights are w⁽¹⁾ = μ_E − μ⁽⁰⁾, whose norm is the start margin t0
    assert r.params.seed == 2 and r.t0 == pytest.approx(float(np.linalg.norm(r.history[0].w)))
    facts = json.loads(json.dumps(r.facts(), default=float))
    assert "weights" not in facts and facts["params"]["seed"] == 2
    assert [h["i"] for h in facts["history"]] == [1] and len(facts["history"][0]["mu"]) == 9
    assert [list(row) for row in r.metric_rows()] == [X.METRIC_COLUMNS]
    pol = r.labelled_policy()
    assert pol.meta["learner"] == "irl" and pol.meta["seed"] == 2 and pol.meta["eval"] is r.metrics
    assert "learner" not in r.policy.meta  # the run's own policy is left as trained
    assert all(isinstance(w, np.ndarray) for w in r.policy.weights + r.policy.biases)


@pytest.mark.slow
def test_a_pool_gives_the_runs_of_this_process():
    p, mu = _tiny_experiment()
    here, pooled = X.run_experiment(p, mu, 1), X.run_experiment(p, mu, 2)
    for a, b in zip(here, pooled, strict=True):
        assert (a.learner, a.seed, a.metrics, a.chosen, a.t0) == (b.learner, b.seed, b.metrics,
                                                                  b.chosen, b.t0)  # fmt: skip
        for wa, wb in zip(a.policy.weights + a.policy.biases, b.policy.weights + b.policy.biases):
            np.testing.assert_array_equal(wa, wb)


def test_references_and_the_best_run():
    p = X.ExperimentParams(seeds=2, eval_episodes=1)
    makers = X.baseline_factories(p)
    assert list(makers) == ["expert (demonstrator)", "expert (ideal)", "random"]
    ms = X.baseline_metrics(makers["random"], p)
    assert len(ms) == 2 and all(0 <= m["all_in_view_frac"] <= 1 for m in ms)
    pol = MLPPolicy([np.zeros((7, 14))], [np.zeros(7)], {})

    def run(learner, seed, view):
        return X.LearnerRun(learner, seed, {"all_in_view_frac": view}, 0.0, 0.0, 0, False, 0.0,
                            [], np.zeros(1), pol, TINY)  # fmt: skip

    runs = [run("irl", 0, 0.5), run("irl", 1, 0.7), run("ab_mean", 0, 0.6), run("ab_mean", 1, 0.6)]
    best = X.best_runs(runs)
    assert (best["irl"].seed, best["ab_mean"].seed) == (1, 0)  # the first one on a tie
