"""The modular policy: one skill module per lesson and an arbiter that reads concepts.

    obs (14,) ──► concepts (quantities; predicates = quantity vs threshold)
                   │
                   ├─► arbiter: an ordered rule list "if predicate p_k then module m_k", else
                   │   the default module (learnt in the composite lesson, policy.education.teach)
                   └─► the chosen module: a Q-network over its own input concepts (predicates as
                       1/0, quantities by value), greedy over its own actions (learnt in its
                       lesson, then frozen)

`policy(obs) → action index` flies like any skyherd policy; `policy.explain(obs)` says which
module acted and why, citing every predicate the decision depends on:

* the reason's path: the arbiter's rule that fired (in the concept's own words), or "none of …
  holds" for the default;
* the cited predicates: for each quantity behind a predicate and each direction (up, down),
  the first threshold past which (by ε = 1e-6·max(|θ|, 1), everything else held) the action
  would change — the edges of the region of the concept space where the policy does what it
  does, a counterfactual the policy computes on its own concept values ("team 0.31 right of
  centre" is the reason for "east"; team_west's −0.08 further down is not cited when crossing
  0.08 already changes the action). A fired rule that is not among them is said to be "not
  decisive"; earlier rules are cited only when making them true would change the action.

A module that reads only predicates depends on nothing else, so the explanation is complete; a
module that also reads quantities by value lists them as `read` (their values are in `concepts`)
without claiming a threshold. policy.education.fidelity measures, with larger moves, how often
crossing a cited / an uncited concept's threshold changes the decision.

File (`.npz`, no pickle; `policy.dqn.load_policy` recognises it): arrays m<i>_W<k>, m<i>_b<k>
(module i's MLP, as policy.dqn.MLPPolicy) and `meta`, a JSON string: format
"skyherd-modular-policy/1", the curriculum's name, version and sha256, the concept definitions
(re-checked by the formula parser on load), the modules (name, lesson, inputs, actions) and the
arbiter's rules.
"""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from skyherd.policy.dqn import MLPPolicy
from skyherd.policy.education.concepts import Concept, ConceptError, compile_concepts, parse_concept
from skyherd.runio.runfolder import atomic_write_bytes, to_jsonable
from skyherd.task.params import ACTION_NAMES, TaskParams, action_velocity_ned

FORMAT = "skyherd-modular-policy/1"


@dataclass
class SkillModule:
    """A skill: Q-network over `inputs` (quantity concepts) → one of `actions` (env indices)."""

    name: str
    lesson: str
    inputs: tuple[str, ...]
    actions: tuple[int, ...]
    net: MLPPolicy

    def act_index(self, x: np.ndarray) -> int:
        return int(np.argmax(self.net.q_values(x)))

    def act(self, feats: dict[str, float]) -> int:
        """Action from concept features (quantities by value, predicates as 1/0: `features`)."""
        return self.actions[self.act_index(np.array([feats[n] for n in self.inputs]))]


def features(values: dict[str, float], preds: list[Concept]) -> dict[str, float]:
    """Quantity values plus every predicate's truth as 1.0 / 0.0 (what a module reads)."""
    f = dict(values)
    for p in preds:
        f[p.name] = 1.0 if p.holds(values[p.quantity]) else 0.0
    return f


def nudge(threshold: float) -> float:
    """ε: how far past a threshold the explanation's counterfactual moves a quantity."""
    return 1e-6 * max(abs(threshold), 1.0)


@dataclass(frozen=True)
class Arbiter:
    """Ordered rules (predicate name, module name); the first predicate that holds picks."""

    rules: tuple[tuple[str, str], ...]
    default: str

    def choose(self, holds: dict[str, bool]) -> tuple[str, int]:
        """(module name, index of the rule that fired, −1 = default)."""
        for k, (p, m) in enumerate(self.rules):
            if holds[p]:
                return m, k
        return self.default, -1

    def describe(self) -> str:
        rows = [f"if {p}: {m}" for p, m in self.rules] + [f"else: {self.default}"]
        return "; ".join(rows)


def _concept_meta(c: Concept) -> dict:
    return {"name": c.name, "formula": c.formula, "unit": c.unit, "text": c.text}


class ModularPolicy:
    """callable(obs) → action; explain(obs) → {module, reason, concepts, action, cited}."""

    def __init__(
        self,
        concepts: list[Concept],
        modules: list[SkillModule],
        arbiter: Arbiter,
        meta: dict[str, Any],
        task: TaskParams | None = None,
    ):
        self.concepts = {c.name: c for c in concepts}
        self.modules = {m.name: m for m in modules}
        self.arbiter = arbiter
        self.task = task or TaskParams()
        for p, m in arbiter.rules + (("", arbiter.default),):
            if m not in self.modules:
                raise ValueError(f"arbiter names module {m!r}, which the policy does not have")
            if p and self.concepts.get(p, Concept("", "", "")).kind != "predicate":
                raise ValueError(f"arbiter rule on {p!r}, which is not a predicate concept")
        for m in modules:
            for n in m.inputs:
                if n not in self.concepts:
                    raise ValueError(f"module {m.name!r} reads {n!r}, not a concept")
            if m.net.obs_dim != len(m.inputs) or m.net.n_actions != len(m.actions):
                raise ValueError(
                    f"module {m.name!r}: network shape does not match its inputs/actions"
                )
        self._values = compile_concepts(concepts, self.task)
        self.meta = dict(meta, format=FORMAT, learner=meta.get("learner", "educated"))
        self.obs_dim, self.n_actions = 14, len(ACTION_NAMES)
        self.preds = [c for c in concepts if c.kind == "predicate"]

    # ---- deciding ---------------------------------------------------------------------------
    def values(self, obs) -> dict[str, float]:
        """Quantity concepts of an observation."""
        obs = np.asarray(obs, np.float64)
        if obs.shape != (14,) or not np.all(np.isfinite(obs)):
            raise ValueError(f"policy expects a finite obs of shape (14,), got {obs.shape}")
        try:
            return self._values(obs)
        except ArithmeticError:  # a formula divided by zero: no concept value
            return {n: math.nan for n, c in self.concepts.items() if c.kind == "quantity"}

    def holds(self, values: dict[str, float]) -> dict[str, bool]:
        return {p.name: p.holds(values[p.quantity]) for p in self.preds}

    def module_action(self, m: str, values: dict[str, float]) -> int:
        return self.modules[m].act(features(values, self.preds))

    def decide(self, values: dict[str, float]) -> tuple[str, int, int]:
        """From quantity values (possibly intervened on): (module, rule index, action)."""
        if not all(math.isfinite(v) for v in values.values()):
            return "", -2, 0  # undefined concepts: hover (the safety net judges the rest)
        m, k = self.arbiter.choose(self.holds(values))
        return m, k, self.module_action(m, values)

    def __call__(self, obs) -> int:
        return self.decide(self.values(obs))[2]

    # ---- explaining -------------------------------------------------------------------------
    def citations(self, values: dict[str, float]) -> dict[str, list[str]]:
        """What a decision's action depends on (module docstring), as predicate names:
        {rule: the fired rule's, if decisive; earlier: earlier rules' that are decisive; module:
        the other decisive ones; named: rules the arbiter went through that are not decisive;
        read: quantities the acting module reads by value}."""
        m, k, a = self.decide(values)
        if k == -2:
            return {"rule": [], "earlier": [], "module": [], "named": [], "read": []}
        rules = self.arbiter.rules
        fired = [rules[k][0]] if k >= 0 else []
        earlier = list(dict.fromkeys(p for p, _ in rules[: len(rules) if k < 0 else k]))
        decisive = set(self._decisive(values, a))
        rest = [n for n in self.modules[m].inputs if n in decisive and n not in fired + earlier]
        rest += [p.name for p in self.preds if p.name in decisive and p.name not in rest
                 and p.name not in fired + earlier]  # fmt: skip
        return {
            "rule": [n for n in fired if n in decisive],
            "earlier": [n for n in earlier if n in decisive],
            "module": rest,
            "named": [n for n in fired + earlier if n not in decisive],
            "read": [n for n in self.modules[m].inputs if self.concepts[n].kind == "quantity"],
        }

    def _decisive(self, values: dict[str, float], a: int) -> list[str]:
        """Per quantity behind any predicate and per direction (up, down): the first threshold
        past which (by ε, all else held) the action changes — the edges of the region of the
        concept space where the policy does what it does. Between two consecutive thresholds of
        a quantity every predicate on it keeps its truth, so for modules that read predicates
        only this is exact."""
        by_q: dict[str, list[Concept]] = {}
        for p in self.preds:
            by_q.setdefault(p.quantity, []).append(p)
        out = []
        for q, ps in by_q.items():
            v = values[q]
            above = [p for p in ps if p.threshold >= v]
            below = [p for p in ps if p.threshold < v]
            for side, ahead in ((1.0, above), (-1.0, below)):
                for t in sorted({p.threshold for p in ahead}, key=lambda t: side * t):
                    v2 = dict(values, **{q: t + side * nudge(t)})
                    if self.decide(v2)[2] != a:  # the action's boundary this way
                        out += [p.name for p in ahead if p.threshold == t]
                        break
        return out

    def _say(self, name: str, values: dict[str, float]) -> str:
        p = self.concepts[name]
        v = values[p.quantity]
        return p.say(v) + f" ({p.formula})" if p.holds(v) else f"not {name} ({p.formula})"

    def explain_values(self, values: dict[str, float]) -> dict[str, Any]:
        m, k, a = self.decide(values)
        rules = self.arbiter.rules
        c = self.citations(values)
        if k == -2:
            reason = "concepts undefined (a formula divided by zero): hover"
        elif k >= 0:
            reason = self._say(rules[k][0], values)
            if not c["rule"]:
                reason += " [not decisive: without it the action is the same]"
        else:
            names = ", ".join(dict.fromkeys(p for p, _ in rules))
            reason = f"none of {names} holds" if names else "the arbiter's only module"
        if c["module"]:
            reason += "; " + ", ".join(self._say(n, values) for n in c["module"])
        cited = c["rule"] + c["earlier"] + c["module"]
        used = {self.concepts[n].quantity for n in cited} | set(c["read"])
        if m:  # the quantities behind every concept the module reads
            ins = [self.concepts[n] for n in self.modules[m].inputs]
            used |= {x.quantity if x.kind == "predicate" else x.name for x in ins}
        return {
            "module": m or "none",
            "reason": reason,
            "concepts": {n: round(v, 4) for n, v in values.items() if n in used},
            "action": ACTION_NAMES[a],
            "cited": cited,
            "read": c["read"],
        }

    def explain(self, obs) -> dict[str, Any]:
        """{module, reason, concepts {name: value}, action (name), cited [predicate names],
        read [quantities the module reads by value]}."""
        return self.explain_values(self.values(obs))

    def describe_action(self, a: int) -> str:
        v = action_velocity_ned(a, self.task.uav)
        return ACTION_NAMES[a] + (f" {max(abs(x) for x in v):g} m/s" if a else "")

    # ---- file -------------------------------------------------------------------------------
    def save(self, path: Path) -> Path:
        arrays: dict[str, np.ndarray] = {}
        mods = []
        for i, m in enumerate(self.modules.values()):
            for k, (W, b) in enumerate(zip(m.net.weights, m.net.biases)):
                arrays[f"m{i}_W{k}"] = W.astype(np.float32)
                arrays[f"m{i}_b{k}"] = b.astype(np.float32)
            mods.append(
                {
                    "name": m.name,
                    "lesson": m.lesson,
                    "inputs": list(m.inputs),
                    "actions": [ACTION_NAMES[a] for a in m.actions],
                    "layers": len(m.net.weights),
                }
            )
        meta = dict(self.meta)
        meta.update(
            {
                "format": FORMAT,
                "obs_dim": 14,
                "n_actions": self.n_actions,
                "concepts": [_concept_meta(c) for c in self.concepts.values()],
                "modules": mods,
                "arbiter": {
                    "rules": [list(r) for r in self.arbiter.rules],
                    "default": self.arbiter.default,
                },
            }
        )
        arrays["meta"] = np.array(json.dumps(to_jsonable(meta)))
        bio = io.BytesIO()
        np.savez_compressed(bio, **arrays)
        atomic_write_bytes(Path(path), bio.getvalue())
        return Path(path)


def from_arrays(z, meta: dict[str, Any], where: str = "") -> ModularPolicy:
    """Rebuild a ModularPolicy from an opened npz and its meta (ValueError on anything wrong)."""
    concepts: list[Concept] = []
    for c in meta["concepts"]:
        qs = {x.name for x in concepts if x.kind == "quantity"}
        try:
            concepts.append(
                parse_concept(c["name"], c["formula"], c["unit"], c.get("text", ""), qs)
            )
        except ConceptError as e:
            raise ValueError(f"concept in the file: {e}") from None
    modules = []
    for i, m in enumerate(meta["modules"]):
        W = [np.asarray(z[f"m{i}_W{k}"]) for k in range(int(m["layers"]))]
        b = [np.asarray(z[f"m{i}_b{k}"]) for k in range(int(m["layers"]))]
        if not all(np.all(np.isfinite(x)) for x in W + b):
            raise ValueError(f"module {m['name']!r} weights contain NaN/inf")
        acts = tuple(ACTION_NAMES.index(a) for a in m["actions"])
        net = MLPPolicy(W, b, {"module": m["name"]})
        modules.append(SkillModule(m["name"], m["lesson"], tuple(m["inputs"]), acts, net))
    arb = meta["arbiter"]
    arbiter = Arbiter(tuple((str(p), str(q)) for p, q in arb["rules"]), str(arb["default"]))
    return ModularPolicy(concepts, modules, arbiter, meta)
