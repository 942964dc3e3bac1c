"""Concepts: named quantities and predicates over the observation (φ(s) and the vehicle state).

A concept is written in the curriculum file as a formula over the *variables* below (decoded from
the 14-float GroundAir observation, SI units) and the *constants* (each read from its one
source: the task, camera and feature parameters). Two kinds:

* quantity   any arithmetic formula:  `formula = "com_u - 0.5"`  (unit: what it measures in)
* predicate  one quantity compared with a number: `formula = "offset_east > 0.08"`, unit "bool";
             its threshold (0.08) is what the arbiter's explanation cites and what the
             explanation-fidelity test moves the quantity across.

Formulas are parsed with `ast` and only numbers, variables, constants, earlier quantities,
+ − * /, unary −, and abs/min/max are accepted; the accepted trees are turned into one Python
function that computes every concept from an observation (no `eval` of unchecked text, no pickle).

Variables (observation index → decoded value; params.py and env.py define the encoding):

==============  ======================================================  ======================
variable        value                                                   unit
==============  ======================================================  ======================
com_u, com_v    UGVs' centre in the image (0.5 = centred; +u east, +v    image width / height
                south)
spread          smallest circle radius / image half-diagonal            half-diagonal
alt_m           altitude φ₃ · altitude_max_m                            m
frac_in_view    UGVs detected / team size                               -
all_in_view     1 when every UGV is detected                            -
edge_margin     nearest UGV's distance to the border / half short side  -
frame_ok        1 when the frame was usable                             -
vel_n, vel_e    UAV velocity north, east                                m/s
vel_d           UAV velocity down                                       m/s
d_com_u, d_com_v, d_spread   change of com_u, com_v, spread over the last step   per step
==============  ======================================================  ======================

Constants: SPREAD_TARGET (TaskParams.spread_target), ALT_MIN_M, ALT_MAX_M (the UAV geofence,
UAVParams), V_XY, V_UP, V_DOWN (the speed commands, UAVParams) [m, m/s].
"""

from __future__ import annotations

import ast
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from skyherd.perception.features import FeatureParams
from skyherd.task.params import TaskParams

VARIABLES: tuple[str, ...] = (
    "com_u",
    "com_v",
    "spread",
    "alt_m",
    "frac_in_view",
    "all_in_view",
    "edge_margin",
    "frame_ok",
    "vel_n",
    "vel_e",
    "vel_d",
    "d_com_u",
    "d_com_v",
    "d_spread",
)
FUNCTIONS = {"abs": abs, "min": min, "max": max}


def constants(task: TaskParams | None = None) -> dict[str, float]:
    task = task or TaskParams()
    u = task.uav
    return {
        "SPREAD_TARGET": task.spread_target,
        "ALT_MIN_M": u.alt_min_m,
        "ALT_MAX_M": u.alt_max_m,
        "V_XY": u.v_xy_mps,
        "V_UP": u.v_up_mps,
        "V_DOWN": u.v_down_mps,
    }


def decode_observation(obs, task: TaskParams | None = None) -> dict[str, float]:
    """The variables (table above) of one observation (14,) (inverse of task.observation.make_observation)."""
    task = task or TaskParams()
    u = task.uav
    o = [float(x) for x in obs]
    vz = max(u.v_up_mps, u.v_down_mps)
    return {
        "com_u": o[0],
        "com_v": o[1],
        "spread": o[2],
        "alt_m": o[3] * FeatureParams().altitude_max_m,
        "frac_in_view": o[4],
        "all_in_view": o[5],
        "edge_margin": o[6],
        "frame_ok": o[7],
        "vel_n": (o[8] - 0.5) * 2 * u.v_xy_mps,
        "vel_e": (o[9] - 0.5) * 2 * u.v_xy_mps,
        "vel_d": (o[10] - 0.5) * 2 * vz,
        "d_com_u": (o[11] - 0.5) / 5.0,
        "d_com_v": (o[12] - 0.5) / 5.0,
        "d_spread": (o[13] - 0.5) / 5.0,
    }


class ConceptError(ValueError):
    """A concept formula that is not in the accepted language (message names the concept)."""


@dataclass(frozen=True)
class Concept:
    """One concept of the ontology (see the module docstring)."""

    name: str
    formula: str
    unit: str
    text: str = ""  # how an explanation says it: "team {value:.2f} right" ({abs}, {threshold})
    kind: str = "quantity"  # "quantity" | "predicate"
    quantity: str = ""  # predicate: the quantity it compares
    op: str = ""  # predicate: ">" or "<"
    threshold: float = math.nan  # predicate: the number it compares with

    def holds(self, value: float) -> bool:
        """Predicate truth for a value of its quantity."""
        return value > self.threshold if self.op == ">" else value < self.threshold

    def across(self, value: float, margin: float) -> float:
        """A value of the quantity just on the other side of this predicate's threshold."""
        side = 1.0 if self.holds(value) else -1.0  # move to where it does not hold, or does
        return self.threshold - side * margin if self.op == ">" else self.threshold + side * margin

    def say(self, value: float) -> str:
        if self.text:
            try:
                return self.text.format(value=value, abs=abs(value), threshold=self.threshold)
            except (KeyError, IndexError, ValueError):
                pass
        return f"{self.name} = {value:.3g}"


_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/"}


def _check_expr(node: ast.AST, names: set[str], where: str) -> None:
    """Accept only the formula language of the module docstring."""
    if isinstance(node, ast.Constant) and isinstance(node.value, int | float):
        if isinstance(node.value, bool):
            raise ConceptError(f"{where}: booleans are not numbers here")
        return
    if isinstance(node, ast.Name):
        if node.id not in names:
            raise ConceptError(f"{where}: unknown name {node.id!r}")
        return
    if isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        _check_expr(node.left, names, where)
        _check_expr(node.right, names, where)
        return
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub | ast.UAdd):
        _check_expr(node.operand, names, where)
        return
    if (
        isinstance(node, ast.Call)
        and isinstance(node.func, ast.Name)
        and node.func.id in FUNCTIONS
        and not node.keywords
        and node.args
    ):
        for a in node.args:
            _check_expr(a, names, where)
        return
    raise ConceptError(f"{where}: {ast.unparse(node)!r} is not allowed in a formula")


def parse_concept(name: str, formula: str, unit: str, text: str, quantities: set[str]) -> Concept:
    """Check one formula; `quantities` are the quantity concepts defined before this one."""
    where = f"concepts.{name}.formula"
    if not name.isidentifier() or name in VARIABLES or name in FUNCTIONS:
        raise ConceptError(f"concepts.{name}: the name must be an identifier, not a variable")
    try:
        tree = ast.parse(formula, mode="eval").body
    except SyntaxError as e:
        raise ConceptError(f"{where}: not a formula ({e.msg})") from None
    consts = set(constants())
    if isinstance(tree, ast.Compare):
        if len(tree.ops) != 1 or not isinstance(tree.ops[0], ast.Gt | ast.Lt):
            raise ConceptError(f"{where}: a predicate is '<quantity> > <number>' or '<'")
        left, right = tree.left, tree.comparators[0]
        if not (isinstance(left, ast.Name) and left.id in quantities):
            raise ConceptError(f"{where}: a predicate compares a quantity concept defined above")
        try:
            thr = float(ast.literal_eval(right))
        except (ValueError, TypeError, SyntaxError):
            raise ConceptError(f"{where}: the threshold must be a number") from None
        if not math.isfinite(thr):
            raise ConceptError(f"{where}: the threshold must be finite")
        op = ">" if isinstance(tree.ops[0], ast.Gt) else "<"
        return Concept(name, formula, unit, text, "predicate", left.id, op, thr)
    _check_expr(tree, set(VARIABLES) | consts | quantities, where)
    return Concept(name, formula, unit, text)


def compile_concepts(
    concepts: list[Concept], task: TaskParams | None = None
) -> Callable[[np.ndarray], dict[str, float]]:
    """obs (14,) → {quantity name: value} for every quantity concept (predicates: see `truth`).

    The formulas were checked by `parse_concept`; they are joined into one function body.
    """
    ns: dict = {"__builtins__": {}, **FUNCTIONS, **constants(task)}
    lines = ["def _f(v):"]
    lines += [f"    {n} = v[{n!r}]" for n in VARIABLES]
    qs = [c for c in concepts if c.kind == "quantity"]
    lines += [f"    {c.name} = ({ast.unparse(ast.parse(c.formula, mode='eval').body)})" for c in qs]
    lines.append("    return {" + ", ".join(f"{c.name!r}: {c.name}" for c in qs) + "}")
    exec(compile("\n".join(lines), "<concepts>", "exec"), ns)  # checked trees only
    f = ns["_f"]

    def values(obs) -> dict[str, float]:
        return {k: float(x) for k, x in f(decode_observation(obs, task)).items()}

    return values
