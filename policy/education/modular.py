"""The modular policy: one skill module per lesson and an arbiter that reads concepts.

    obs (14,) ──► concepts (quantities; predicates = quantity vs threshold)
                   │
                   ├─► arbiter: an ordered rule list "if predicate p_k then module m_k", else
                   │   the default module (learnt in the composite lesson, policy.education.teach)
                   └─► the chosen module: a Q-network over its own input quantities, greedy over
                       its own actions (learnt in its lesson, then frozen)

`policy(obs) → action index` flies like any skyherd policy; `policy.explain(obs)` says which
module acted, why (the rule that fired, in the concept's own words, and the earlier rules that
did not), the concept values and the action. Because the arbiter only sees predicates, the
concepts named in the reason are exactly the ones that decided the module: the fidelity test
(policy.education.fidelity) measures how often moving one across its threshold changes the action.

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

from policy.dqn import MLPPolicy
from policy.education.concepts import Concept, ConceptError, compile_concepts, parse_concept
from policy.groundair.params import ACTION_NAMES, TaskParams, action_velocity_ned
from runio.runfolder import atomic_write_bytes, to_jsonable

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

    def act(self, values: dict[str, float]) -> int:
        return self.actions[self.act_index(np.array([values[n] for n in self.inputs]))]


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
                if self.concepts.get(n, Concept("", "", "", kind="?")).kind != "quantity":
                    raise ValueError(f"module {m.name!r} reads {n!r}, not a quantity concept")
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

    def decide(self, values: dict[str, float]) -> tuple[str, int, int]:
        """From quantity values (possibly intervened on): (module, rule index, action)."""
        if not all(math.isfinite(v) for v in values.values()):
            return "", -2, 0  # undefined concepts: hover (the safety net judges the rest)
        m, k = self.arbiter.choose(self.holds(values))
        return m, k, self.modules[m].act(values)

    def __call__(self, obs) -> int:
        return self.decide(self.values(obs))[2]

    # ---- explaining -------------------------------------------------------------------------
    def cited(self, k: int) -> tuple[list[str], list[str]]:
        """Quantities the reason names for a decision by rule k: (the rule's, the earlier rules')."""
        rules = self.arbiter.rules
        upto = len(rules) if k < 0 else k
        earlier = [self.concepts[p].quantity for p, _ in rules[:upto]]
        own = [self.concepts[rules[k][0]].quantity] if k >= 0 else []
        return own, [q for q in dict.fromkeys(earlier) if q not in own]

    def explain_values(self, values: dict[str, float]) -> dict[str, Any]:
        m, k, a = self.decide(values)
        rules = self.arbiter.rules
        if k == -2:
            reason = "concepts undefined (a formula divided by zero): hover"
        elif k >= 0:
            p = self.concepts[rules[k][0]]
            reason = p.say(values[p.quantity]) + f" ({p.formula})"
        else:
            names = ", ".join(dict.fromkeys(p for p, _ in rules))
            reason = f"none of {names} holds" if names else "the arbiter's only module"
        own, earlier = self.cited(k) if k > -2 else ([], [])
        used = set(own + earlier) | (set(self.modules[m].inputs) if m else set())
        return {
            "module": m or "none",
            "reason": reason,
            "concepts": {n: round(v, 4) for n, v in values.items() if n in used},
            "action": ACTION_NAMES[a],
            "cited": own + earlier,
        }

    def explain(self, obs) -> dict[str, Any]:
        """{module, reason, concepts {name: value}, action (name), cited [quantity names]}."""
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
