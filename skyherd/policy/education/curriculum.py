"""The curriculum file: concepts, lessons in semantic order, the composite lesson (TOML).

Format `skyherd-curriculum/1` (the default is curricula/groundair.toml; docs/education.md):

    format = "skyherd-curriculum/1"
    name = "groundair"
    version = "1.0.0"                       # the curriculum's own version (saved in the policy)

    [concepts.offset_east]                  # a quantity ...
    formula = "com_u - 0.5"
    unit = "image width"
    text = "team {value:+.2f} east of centre"
    [concepts.team_east]                    # ... and a predicate on it (threshold 0.08)
    formula = "offset_east > 0.08"
    unit = "bool"

    [[lessons]]                             # in teaching order
    name = "lateral"
    scenario = "lateral"                    # a GroundAir scenario
    teaches = ["offset_east", "team_east"]  # concepts this lesson introduces
    module = "lateral"                      # the skill module it trains (one per lesson)
    inputs = ["team_east"]                  # concepts the module reads (taught by now): predicates
                                            # (0/1; explanations cite them exactly) or quantities
    actions = ["hover", "east", "west"]     # the module's actions (params.ACTION_NAMES)
    method = "irl"                          # irl: projection IRL on its demos | dqn: on `reward`
    demos = "scripted"                      # scripted expert, or a demo file (.npz) path
    warm_start = "demos"                    # "demos": behaviour cloning first, the demos kept in
                                            # every TD step (DQfD, policy.education.dqfd) | "none"
    pass = {all_in_view_frac = ">= 0.9"}    # pass criterion (also the retention score)
    requires = []                           # earlier lessons it builds on

    [composite]                             # the last lesson: trains the arbiter only
    name = "composite"
    scenario = "composite"
    method = "ab"                           # ab: μ_E from the lessons' demos | irl: `demos` | reward
    arbiter_inputs = ["team_east"]          # predicates only (the arbiter reads concepts)
    retention_weight = 1.0                  # the arbiter search also replays the skill lessons
                                            # (their μ_E on their scenarios; 0 = composite only)
    modules = ["lateral"]
    requires = ["lateral"]
    pass = {all_in_view_frac = ">= 0.9"}

Errors are one line naming the key (`CurriculumError`). The semantic-order check refuses a
lesson that uses (module inputs, arbiter inputs, a predicate's quantity) a concept that neither
it nor an earlier lesson teaches.
"""

from __future__ import annotations

import hashlib
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from skyherd.policy.education.concepts import Concept, ConceptError, parse_concept
from skyherd.policy.groundair.env import PSI_NAMES
from skyherd.task.params import ACTION_NAMES
from skyherd.task.scenarios import GROUNDSIM_SCENARIOS, SCENARIOS

FORMAT = "skyherd-curriculum/1"
DEFAULT_CURRICULUM = Path(__file__).with_name("curricula") / "groundair.toml"
MODULE_METHODS = ("irl", "dqn")
COMPOSITE_METHODS = ("ab", "irl", "reward", "measures")
METRICS = ("all_in_view_frac", "footprint_ratio", "ugv_losses")
KEEP = ("freeze",)
WARM_STARTS = ("none", "demos")


class CurriculumError(ValueError):
    """A curriculum that cannot be taught: one line, naming the key."""


@dataclass(frozen=True)
class PassCriterion:
    metric: str
    op: str  # ">=" or "<="
    value: float

    def ok(self, metrics: dict[str, float]) -> bool:
        v = metrics.get(self.metric, float("nan"))
        return v >= self.value if self.op == ">=" else v <= self.value

    def __str__(self) -> str:
        return f"{self.metric} {self.op} {self.value:g}"


@dataclass(frozen=True)
class Lesson:
    name: str
    scenario: str
    teaches: tuple[str, ...]
    module: str
    inputs: tuple[str, ...]
    actions: tuple[int, ...]
    method: str
    demos: str = "scripted"
    reward: tuple[float, ...] = ()  # ψ weights (method dqn)
    passes: tuple[PassCriterion, ...] = ()
    requires: tuple[str, ...] = ()
    keep: str = "freeze"
    warm_start: str = "none"  # "demos": DQfD pre-training (behaviour cloning) + J_E in every step


@dataclass(frozen=True)
class CompositeLesson:
    name: str
    scenario: str
    method: str
    arbiter_inputs: tuple[str, ...]
    modules: tuple[str, ...]
    requires: tuple[str, ...] = ()
    teaches: tuple[str, ...] = ()
    passes: tuple[PassCriterion, ...] = ()
    demos: str = "scripted"
    reward: tuple[float, ...] = ()
    ab_rule: str = "mean"
    retention_weight: float = 0.0  # weight of the skill lessons' replay in the arbiter objective


@dataclass(frozen=True)
class Curriculum:
    name: str
    version: str
    sha256: str  # of the file's bytes
    concepts: dict[str, Concept] = field(default_factory=dict)
    lessons: tuple[Lesson, ...] = ()
    composite: CompositeLesson | None = None
    path: str = ""

    def concept_list(self) -> list[Concept]:
        return list(self.concepts.values())

    def lesson(self, name: str) -> Lesson:
        return next(le for le in self.lessons if le.name == name)


# --------------------------------------------------------------------------- helpers
def _err(key: str, msg: str) -> CurriculumError:
    return CurriculumError(f"{key}: {msg}")


def _get(d: dict, key: str, where: str, typ, default=...):
    if key not in d:
        if default is ...:
            raise _err(f"{where}.{key}", "missing")
        return default
    v = d[key]
    if not isinstance(v, typ) or isinstance(v, bool) and typ is not bool:
        raise _err(f"{where}.{key}", f"expected {getattr(typ, '__name__', typ)}, got {v!r}")
    return v


def _names(d: dict, key: str, where: str, default=...) -> tuple[str, ...]:
    v = _get(d, key, where, list, default)
    if not all(isinstance(x, str) for x in v):
        raise _err(f"{where}.{key}", "expected a list of names")
    if len(set(v)) != len(v):
        raise _err(f"{where}.{key}", "a name appears twice")
    return tuple(v)


def _passes(d: dict, where: str) -> tuple[PassCriterion, ...]:
    raw = _get(d, "pass", where, dict, {})
    out = []
    for metric, rule in raw.items():
        key = f"{where}.pass.{metric}"
        if metric not in METRICS:
            raise _err(key, f"unknown metric; choose from {', '.join(METRICS)}")
        m = re.fullmatch(r"\s*(>=|<=)\s*([-+0-9.eE]+)\s*", str(rule))
        if not m:
            raise _err(key, f"expected '>= NUMBER' or '<= NUMBER', got {rule!r}")
        try:
            out.append(PassCriterion(metric, m.group(1), float(m.group(2))))
        except ValueError:
            raise _err(key, f"not a number: {m.group(2)!r}") from None
    return tuple(out)


def _reward(d: dict, where: str, required: bool) -> tuple[float, ...]:
    if "reward" not in d:
        if required:
            raise _err(f"{where}.reward", "missing (weights over " + ", ".join(PSI_NAMES) + ")")
        return ()
    raw = _get(d, "reward", where, dict)
    bad = [k for k in raw if k not in PSI_NAMES]
    if bad:
        raise _err(
            f"{where}.reward.{bad[0]}", f"unknown feature; choose from {', '.join(PSI_NAMES)}"
        )
    for k, v in raw.items():
        if not isinstance(v, int | float) or isinstance(v, bool):
            raise _err(f"{where}.reward.{k}", f"expected a number, got {v!r}")
    return tuple(float(raw.get(n, 0.0)) for n in PSI_NAMES)


def _scenario(d: dict, where: str) -> str:
    sc = _get(d, "scenario", where, str)
    if sc not in SCENARIOS + GROUNDSIM_SCENARIOS:
        raise _err(
            f"{where}.scenario", f"unknown scenario {sc!r}; choose from {', '.join(SCENARIOS)}"
        )
    return sc


def _demos(d: dict, where: str, base: Path) -> str:
    v = _get(d, "demos", where, str, "scripted")
    if v != "scripted":
        p = Path(v) if Path(v).is_absolute() else base / v
        if not p.is_file():
            raise _err(f"{where}.demos", f'no demonstration file {p} (or use "scripted")')
        v = str(p)
    return v


# --------------------------------------------------------------------------- loading
def load_curriculum(path: str | Path) -> Curriculum:
    """Read, validate and order-check a curriculum file. CurriculumError (one line) if bad."""
    path = Path(path)
    try:
        raw_bytes = path.read_bytes()
    except OSError as e:
        raise CurriculumError(f"{path}: cannot read ({e.strerror})") from None
    try:
        doc = tomllib.loads(raw_bytes.decode("utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise CurriculumError(f"{path}: not TOML ({e})") from None
    try:
        return parse_curriculum(doc, hashlib.sha256(raw_bytes).hexdigest(), path)
    except CurriculumError as e:
        raise CurriculumError(f"{path}: {e}") from None


def parse_curriculum(doc: dict, sha256: str, path: Path = Path(".")) -> Curriculum:
    fmt = doc.get("format")
    if fmt != FORMAT:
        raise _err("format", f"{fmt!r}, expected {FORMAT!r}")
    name = _get(doc, "name", "curriculum", str)
    version = _get(doc, "version", "curriculum", str)
    if not re.fullmatch(r"\d+(\.\d+){0,3}", version):
        raise _err("version", f"expected a version like 1.0.0, got {version!r}")
    known = {"format", "name", "version", "concepts", "lessons", "composite", "description"}
    extra = sorted(set(doc) - known)
    if extra:
        raise _err(extra[0], "unknown key")

    # concepts, in file order (a predicate refers to a quantity defined above it)
    concepts: dict[str, Concept] = {}
    for cname, body in _get(doc, "concepts", "curriculum", dict).items():
        where = f"concepts.{cname}"
        if not isinstance(body, dict):
            raise _err(where, "expected a table with formula and unit")
        formula = _get(body, "formula", where, str)
        unit = _get(body, "unit", where, str)
        text = _get(body, "text", where, str, "")
        quantities = {n for n, c in concepts.items() if c.kind == "quantity"}
        try:
            concepts[cname] = parse_concept(cname, formula, unit, text, quantities)
        except ConceptError as e:
            raise CurriculumError(str(e)) from None
    if not concepts:
        raise _err("concepts", "no concepts defined")

    base = path.parent
    lessons: list[Lesson] = []
    raw_lessons = _get(doc, "lessons", "curriculum", list)
    if not raw_lessons:
        raise _err("lessons", "no lessons")
    modules: set[str] = set()
    for i, ld in enumerate(raw_lessons):
        where = f"lessons[{i}]"
        if not isinstance(ld, dict):
            raise _err(where, "expected a table")
        lname = _get(ld, "name", where, str)
        where = f"lessons[{i}] ({lname})"
        method = _get(ld, "method", where, str)
        if method not in MODULE_METHODS:
            raise _err(f"{where}.method", f"{method!r}; choose from {', '.join(MODULE_METHODS)}")
        acts = _names(ld, "actions", where)
        bad = [a for a in acts if a not in ACTION_NAMES]
        if bad or len(acts) < 2:
            raise _err(f"{where}.actions", f"need ≥ 2 of {', '.join(ACTION_NAMES)}")
        module = _get(ld, "module", where, str)
        keep = _get(ld, "keep", where, str, "freeze")
        if keep not in KEEP:
            raise _err(f"{where}.keep", f"{keep!r}; choose from {', '.join(KEEP)}")
        if module in modules:
            raise _err(
                f"{where}.module", f"module {module!r} is already taught by an earlier lesson"
            )
        modules.add(module)
        warm = _get(ld, "warm_start", where, str, "none")
        if warm not in WARM_STARTS:
            raise _err(f"{where}.warm_start", f"{warm!r}; choose from {', '.join(WARM_STARTS)}")
        lessons.append(
            Lesson(
                name=lname,
                scenario=_scenario(ld, where),
                teaches=_names(ld, "teaches", where),
                module=module,
                inputs=_names(ld, "inputs", where),
                actions=tuple(ACTION_NAMES.index(a) for a in acts),
                method=method,
                demos=_demos(ld, where, base),
                reward=_reward(ld, where, method == "dqn"),
                passes=_passes(ld, where),
                requires=_names(ld, "requires", where, ()),
                keep=keep,
                warm_start=warm,
            )
        )
    composite = None
    if "composite" in doc:
        cd = _get(doc, "composite", "curriculum", dict)
        where = "composite"
        method = _get(cd, "method", where, str)
        if method not in COMPOSITE_METHODS:
            raise _err(f"{where}.method", f"{method!r}; choose from {', '.join(COMPOSITE_METHODS)}")
        from skyherd.policy.ab import RULES

        rule = _get(cd, "ab_rule", where, str, "mean")
        if rule not in RULES:
            raise _err(f"{where}.ab_rule", f"{rule!r}; choose from {', '.join(RULES)}")
        rw = _get(cd, "retention_weight", where, int | float, 0.0)
        if isinstance(rw, bool) or not 0.0 <= rw < float("inf"):
            raise _err(f"{where}.retention_weight", f"expected a number >= 0, got {rw!r}")
        composite = CompositeLesson(
            name=_get(cd, "name", where, str, "composite"),
            scenario=_scenario(cd, where),
            method=method,
            arbiter_inputs=_names(cd, "arbiter_inputs", where),
            modules=_names(cd, "modules", where),
            requires=_names(cd, "requires", where, ()),
            teaches=_names(cd, "teaches", where, ()),
            passes=_passes(cd, where),
            demos=_demos(cd, where, base),
            reward=_reward(cd, where, method == "reward"),
            ab_rule=rule,
            retention_weight=float(rw),
        )
    cur = Curriculum(name, version, sha256, concepts, tuple(lessons), composite, str(path))
    check_semantic_order(cur)
    return cur


def check_semantic_order(cur: Curriculum) -> None:
    """Refuse a lesson that uses a concept not taught by itself or an earlier lesson."""
    taught_by: dict[str, str] = {}
    order = list(cur.lessons) + ([cur.composite] if cur.composite else [])
    for le in order:
        for c in le.teaches:
            if c not in cur.concepts:
                raise _err(f"lesson {le.name!r}.teaches", f"concept {c!r} is not defined")
            if c in taught_by:
                raise _err(
                    f"lesson {le.name!r}.teaches",
                    f"concept {c!r} is already taught by lesson {taught_by[c]!r}",
                )
    taught: dict[str, str] = {}
    earlier: list[str] = []
    for le in order:
        for c in le.teaches:
            taught[c] = le.name
        is_comp = le is cur.composite
        uses = list(le.arbiter_inputs if is_comp else le.inputs)
        uses += [
            cur.concepts[c].quantity for c in le.teaches if cur.concepts[c].kind == "predicate"
        ]
        for c in uses:
            if c not in cur.concepts:
                raise _err(f"lesson {le.name!r}", f"uses concept {c!r}, which is not defined")
            if c not in taught:
                later = next((o.name for o in order if c in o.teaches), None)
                why = f"taught later, by lesson {later!r}" if later else "taught by no lesson"
                raise _err(f"lesson {le.name!r}", f"uses concept {c!r} before it is taught ({why})")
        for c in uses[: len(le.arbiter_inputs)] if is_comp else ():
            if cur.concepts[c].kind != "predicate":  # module inputs: quantities or predicates
                raise _err(
                    f"lesson {le.name!r}.arbiter_inputs",
                    f"{c!r} is a {cur.concepts[c].kind}; arbiter_inputs take predicates",
                )
        for r in le.requires:
            if r not in earlier:
                raise _err(f"lesson {le.name!r}.requires", f"{r!r} is not an earlier lesson")
        if is_comp:
            known = {x.module for x in cur.lessons}
            for m in le.modules:
                if m not in known:
                    raise _err("composite.modules", f"no lesson trains module {m!r}")
            if len(le.modules) < 1:
                raise _err("composite.modules", "needs at least one module")
        earlier.append(le.name)
