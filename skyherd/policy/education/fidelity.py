"""Explanation fidelity: do the concepts an explanation cites decide the action?

For each recorded decision (its observation), the concept values are computed, then one concept
is moved across a predicate's threshold with every other concept held fixed (an intervention on
the concept bottleneck, as in concept-bottleneck models), and the decision is taken again from
the changed values. Two sizes of move past the threshold θ:

* near  `margin(θ) = 0.1·max(|θ|, 0.01)` (issue 14's "just across")
* far   a uniform draw in [0.02, 0.5]·max(|θ|, 0.01) (seeded): a cited concept must decide the
        action wherever it is on the other side, not only next to the threshold

The explanation (ModularPolicy.citations) finds what it cites with a move of only
ε = 1e-6·max(|θ|, 1), so both sizes test it on moves it never made. Roles of a predicate:

* cited_rule            the arbiter's rule that fired (made false), cited as decisive
* cited_earlier         an earlier rule, false so it did not fire (made true), cited
* cited_module          any other cited predicate (in the default curriculum: the module's)
* named_not_decisive    a rule the arbiter went through (fired or earlier) that the
                        explanation says is not decisive
* uncited_same_quantity not cited, but its quantity is that of a cited predicate (moving it
                        may cross the cited threshold too: e.g. team_west's from 0.31 to −0.09
                        also makes team_east false)
* uncited_read          not cited; its quantity is read by value by the acting module
* uncited_other         every other predicate of the curriculum

Rates are reported for the action (what flies) and for the acting module.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from skyherd.policy.education.modular import ModularPolicy

ROLES = (
    "cited_rule",
    "cited_earlier",
    "cited_module",
    "named_not_decisive",
    "uncited_same_quantity",
    "uncited_read",
    "uncited_other",
)


def margin(threshold: float) -> float:
    return 0.1 * max(abs(threshold), 0.01)


def _row() -> dict[str, int]:
    return {"n": 0, "action_changed": 0, "module_changed": 0, "action_changed_far": 0}


def roles(policy: ModularPolicy, values: dict[str, float]) -> list[tuple[str, str]]:
    """(role, predicate name) for every predicate of the policy at one decision."""
    c = policy.citations(values)
    out = [("cited_rule", n) for n in c["rule"]]
    out += [("cited_earlier", n) for n in c["earlier"]]
    out += [("cited_module", n) for n in c["module"]]
    cited = {n for _, n in out}
    out += [("named_not_decisive", n) for n in c["named"]]
    cited_q = {policy.concepts[n].quantity for n in cited}
    read = set(c["read"])
    for p in policy.preds:
        if p.name in cited or p.name in c["named"]:
            continue
        if p.quantity in cited_q:
            out.append(("uncited_same_quantity", p.name))
        elif p.quantity in read:
            out.append(("uncited_read", p.name))
        else:
            out.append(("uncited_other", p.name))
    return out


def fidelity(
    policy: ModularPolicy, observations: Iterable[np.ndarray], seed: int = 0
) -> dict[str, dict]:
    """Counts per role (module docstring) → {role: {n, action_changed, module_changed,
    action_changed_far, action_rate, module_rate, action_rate_far}}."""
    rows = {k: _row() for k in ROLES}
    rng = np.random.default_rng(seed)
    for obs in observations:
        vals = policy.values(obs)
        m, k, a = policy.decide(vals)
        if k == -2:
            continue
        for role, pname in roles(policy, vals):
            p = policy.concepts[pname]
            scale = max(abs(p.threshold), 0.01)
            v2 = dict(vals)
            v2[p.quantity] = p.across(vals[p.quantity], margin(p.threshold))
            m2, _, a2 = policy.decide(v2)
            v2[p.quantity] = p.across(vals[p.quantity], float(rng.uniform(0.02, 0.5)) * scale)
            a3 = policy.decide(v2)[2]
            r = rows[role]
            r["n"] += 1
            r["action_changed"] += int(a2 != a)
            r["module_changed"] += int(m2 != m)
            r["action_changed_far"] += int(a3 != a)
    for r in rows.values():
        n = max(r["n"], 1)
        r["action_rate"] = r["action_changed"] / n
        r["module_rate"] = r["module_changed"] / n
        r["action_rate_far"] = r["action_changed_far"] / n
    return rows


def decision_observations(policy, scenario: str, episodes: int, seed: int) -> list[np.ndarray]:
    """The observations at which `policy` decided on `episodes` test episodes of a scenario."""
    from skyherd.policy.groundair.env import GroundAirEnv

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
