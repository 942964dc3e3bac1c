"""Explanations cite every predicate a decision depends on, and the fidelity measurement agrees:
crossing a cited concept's threshold changes the decision, crossing an uncited one does not."""

import numpy as np

from skyherd.policy.demos import ExpertParams, scripted_expert
from skyherd.policy.dqn import MLPPolicy
from skyherd.policy.education.curriculum import DEFAULT_CURRICULUM, load_curriculum
from skyherd.policy.education.fidelity import fidelity, roles
from skyherd.policy.education.modular import Arbiter, ModularPolicy, SkillModule
from skyherd.policy.groundair.env import GroundAirEnv


def _linear(inputs, actions, q: dict[int, dict[str, float]], bias: dict[int, float]):
    """A one-layer Q-network: Q[a] = bias[a] + Σ q[a][input] · input."""
    W = np.array([[q.get(a, {}).get(n, 0.0) for n in inputs] for a in actions])
    b = np.array([bias.get(a, 0.0) for a in actions])
    return MLPPolicy([W], [b], {})


def _policy(lateral_reads_value: bool = False) -> ModularPolicy:
    cur = load_curriculum(DEFAULT_CURRICULUM)
    lat = cur.lesson("lateral")
    ins = lat.inputs + (("aim_east",) if lateral_reads_value else ())
    # hover 0.5; east/west when the team is east/west of centre, north/south a little weaker
    qs = {1: {"team_north": 0.9}, 2: {"team_south": 0.9}, 3: {"team_east": 1.0},
          4: {"team_west": 1.0}}  # fmt: skip
    if lateral_reads_value:
        qs[3]["aim_east"] = 3.0  # …and east harder the further east (a value, no threshold)
    lateral = SkillModule("lateral", "lateral", ins, lat.actions,
                          _linear(ins, lat.actions, qs, {0: 0.5}))  # fmt: skip
    cl = cur.lesson("climb")
    climb = SkillModule("climb", "climb", cl.inputs, cl.actions,
                        _linear(cl.inputs, cl.actions, {5: {"someone_out": 1.0}}, {0: 0.5}))  # fmt: skip
    arb = Arbiter((("someone_out", "climb"),), "lateral")
    return ModularPolicy(cur.concept_list(), [lateral, climb], arb, {"curriculum": {}})


def _observations(n_steps=120, seed=300_000):
    env = GroundAirEnv("composite")
    ex = scripted_expert("composite", ExpertParams(epsilon=0.3), 1)  # a varied flight …
    obs, _ = env.reset(seed=seed)
    out = []
    for k in range(n_steps):
        out.append(obs)
        obs, _, term, trunc, _ = env.step(ex(obs) if k % 40 < 25 else 0)  # … UGVs leave view
        if term or trunc:
            obs, _ = env.reset(seed=seed + len(out))
    return out


def test_the_explanation_cites_the_module_part_in_concept_words():
    pol = _policy()
    o = np.full(14, 0.5, np.float32)
    o[0], o[4], o[5] = 0.81, 1.0, 1.0  # every UGV in view, team 0.31 right of centre
    ex = pol.explain(o)
    assert ex["module"] == "lateral" and ex["action"] == "east"
    assert ex["cited"] == ["someone_out", "team_east"]  # the rule that had to be false, then why
    assert ex["reason"] == "none of someone_out holds; team 0.31 right of centre (aim_east > 0.08)"
    assert ex["concepts"]["aim_east"] == 0.31 and ex["read"] == []
    o[0] = 0.5  # centred: the lateral module hovers, and would move if any offset crossed 0.08
    ex = pol.explain(o)
    assert ex["action"] == "hover"
    assert set(ex["cited"]) == {"someone_out", "team_east", "team_west", "team_south", "team_north"}
    assert "mostly_east_west" not in ex["cited"]  # this module never reads it to decide


def test_fidelity_cited_concepts_decide_uncited_do_not():
    pol = _policy()
    obs = _observations()
    rows = fidelity(pol, obs)
    for role in ("cited_rule", "cited_earlier", "cited_module"):
        assert rows[role]["n"] > 0 and rows[role]["action_rate"] >= 0.9, (role, rows[role])
        assert rows[role]["action_rate_far"] >= 0.9, (role, rows[role])
    assert rows["uncited_other"]["n"] > 0
    assert rows["uncited_other"]["action_rate"] == 0.0
    assert rows["uncited_other"]["action_rate_far"] == 0.0
    assert rows["uncited_read"]["n"] == 0  # this policy reads no quantity by value


def test_a_module_reading_a_value_says_so():
    pol = _policy(lateral_reads_value=True)
    o = np.full(14, 0.5, np.float32)
    o[0], o[4], o[5] = 0.81, 1.0, 1.0
    ex = pol.explain(o)
    assert ex["read"] == ["aim_east"] and ex["action"] == "east"
    # roles: nothing read by value is passed off as not depending on it
    r = dict((n, role) for role, n in roles(pol, pol.values(o)))
    assert r["team_east"] == "cited_module" and r["team_west"] == "uncited_same_quantity"


def test_the_module_part_walks_to_the_threshold_where_the_action_changes():
    """A module that goes east unless the team is west of centre: at +0.31 its action does not
    change at team_east's 0.08, only at team_west's −0.08, so that is what it cites."""
    pol = _policy()
    lat = pol.modules["lateral"]
    qs = {3: {"team_west": -2.0}, 4: {"team_west": 1.0}}
    lat.net = _linear(lat.inputs, lat.actions, qs, {0: 0.5, 3: 1.0})
    o = np.full(14, 0.5, np.float32)
    o[0], o[4], o[5] = 0.81, 1.0, 1.0
    ex = pol.explain(o)
    assert ex["action"] == "east" and ex["cited"] == ["someone_out", "team_west"]
    assert ex["reason"].endswith("; not team_west (aim_east < -0.08)")
    rows = fidelity(pol, _observations(60))
    assert rows["cited_module"]["action_rate"] == 1.0
    assert rows["uncited_other"]["action_rate"] == 0.0
