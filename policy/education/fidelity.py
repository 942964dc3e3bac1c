"""Explanation fidelity: do the concepts an explanation cites decide the action?

For each recorded decision (its observation), the concept values are computed, then one concept
is moved across a predicate's threshold with every other concept held fixed (an intervention on
the concept bottleneck, as in concept-bottleneck models), and the decision is taken again from
the changed values. The quantity is put `margin(θ) = 0.1·max(|θ|, 0.01)` beyond the threshold θ.

* cited, deciding rule   the fired rule's predicate is made false → does the action change?
* cited, earlier rules   an earlier rule's predicate (false, so the rule did not fire) made true
* not cited              every other predicate of the curriculum, moved across its threshold;
                         split by whether the acting module reads that quantity as an input

Rates are reported for the action (what flies) and for the acting module.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from policy.education.modular import ModularPolicy


def margin(threshold: float) -> float:
    return 0.1 * max(abs(threshold), 0.01)


def _row() -> dict[str, int]:
    return {"n": 0, "action_changed": 0, "module_changed": 0}


def fidelity(policy: ModularPolicy, observations: Iterable[np.ndarray]) -> dict[str, dict]:
    """Counts per role (module docstring) → {role: {n, action_changed, module_changed, rates}}."""
    rows = {
        k: _row() for k in ("cited_rule", "cited_earlier", "uncited_other", "uncited_module_input")
    }
    preds = policy.preds
    by_name = {p.name: p for p in preds}
    rules = policy.arbiter.rules
    for obs in observations:
        vals = policy.values(obs)
        m, k, a = policy.decide(vals)
        if k == -2:
            continue
        own, earlier = policy.cited(k)
        tests: list[tuple[str, str]] = []  # (role, predicate name)
        if k >= 0:
            tests.append(("cited_rule", rules[k][0]))
        tests += [("cited_earlier", p) for p, _ in rules[: (k if k >= 0 else len(rules))]]
        cited = set(own) | set(earlier)
        inputs = set(policy.modules[m].inputs)
        for p in preds:
            if p.quantity not in cited:
                role = "uncited_module_input" if p.quantity in inputs else "uncited_other"
                tests.append((role, p.name))
        for role, pname in tests:
            p = by_name[pname]
            v2 = dict(vals)
            v2[p.quantity] = p.across(vals[p.quantity], margin(p.threshold))
            m2, _, a2 = policy.decide(v2)
            r = rows[role]
            r["n"] += 1
            r["action_changed"] += int(a2 != a)
            r["module_changed"] += int(m2 != m)
    for r in rows.values():
        n = max(r["n"], 1)
        r["action_rate"] = r["action_changed"] / n
        r["module_rate"] = r["module_changed"] / n
    return rows


def decision_observations(policy, scenario: str, episodes: int, seed: int) -> list[np.ndarray]:
    """The observations at which `policy` decided on `episodes` test episodes of a scenario."""
    from policy.groundair.env import GroundAirEnv

    env = GroundAirEnv(scenario)
    out = []
    for e in range(episodes):
        obs, _ = env.reset(seed=seed + e)
        done = False
        while not done:
            out.append(obs)
            obs, _, term, trunc, _ = env.step(policy(obs))
            done = term or trunc
    return out
