"""The verdict of a drill campaign over its rows (safety.campaign_run's metrics.csv rows, live
or read back): the exit rule (`failed_drills`), the tables (`summarize`) and what the campaign
proves (`bounds`).

Every drill is judged by safety.judge (the checks of `skyherd fly` and a drill's own; the row's
`passed` and `failed_check`, the first that failed). Exit rule: the campaign fails when any drill
failed a check or crashed (not judged, never a pass). The tables count the checks' terms:
breaches (fence: the net's flight, ground truth up to the stopping time + RUN_ON_S after a
yield), overridden failsafes (modes), the autopilot's own HOLD beyond the fence after a yield
(failsafe: the built-in vehicle fits its HOLD to the uploaded fence), not recovered (recovered).
The autopilot's own RTL / LAND path after a yield (PX4's RTL flies straight home and does not
route around a fence; the net must not undo it) is reported in its own column and fails no
check: it is the autopilot's failsafe, and the fence and home are the mission planner's to choose
so that the line home stays inside.

What the campaign proves (`bounds`): per airframe and per kind, the drills, the breaches and the
one-sided 95 % Clopper–Pearson upper bound on the breach probability (a crash counts as a breach:
it was not judged), and how many breach-free drills a target bound needs (TARGET_BOUND 1e-3:
2,995).
"""

from __future__ import annotations

import math

import numpy as np

from skyherd.runio.constants import TARGET_BOUND
from skyherd.runio.runfolder import markdown_table
from skyherd.safety.campaign import (
    CONFIDENCE,
    breach_upper_bound,
    drill_index,
    drill_kind,
    drills_needed,
)
from skyherd.safety.judge import FAILSAFE_PATH_MODES


def drill_passed(row: dict) -> bool:
    """The drill passed every check of safety.judge (a crashed drill never passes)."""
    return _flag(row, "passed")


def failed_drills(rows: list[dict]) -> int:
    """The campaign's exit rule: the drills that failed a check or crashed. The campaign
    passes (`skyherd drill --campaign` exits 0) when this is 0."""
    return sum(not drill_passed(r) for r in rows)


def summarize(rows: list[dict]) -> tuple[str, str, str, int]:
    """(per airframe × kind table, closest approaches table, totals line, drills failing a
    check or crashed: the exit rule)."""
    keys = sorted({(r["airframe"], r["kind"]) for r in rows})
    keys += [(a, "all") for a in sorted({r["airframe"] for r in rows})]
    out = []
    for a, k in keys:
        rs = [r for r in rows if r["airframe"] == a and k in ("all", r["kind"])]
        c = [r["min_clearance_m"] for r in rs if math.isfinite(r["min_clearance_m"])] or [math.nan]
        own = [_own(r) for r in rs if _own(r) is not None]
        out.append([a, k, len(rs), _flag_sum(rs, "passed"), _flag_sum(rs, "breach"),
                    sum(int(r["overridden"]) for r in rs), _flag_sum(rs, "not_recovered"),
                    sum(bool(r["yielded"]) for r in rs),
                    sum(_own_counts(r) for r in rs), sum(_own_path(r) for r in rs),
                    max(x for x, _ in own) if own else "-",
                    min(c), float(np.median(c))])  # fmt: skip
    table = markdown_table(["airframe", "kind", "drills", "passed", "breaches", "overridden failsafes",
                            "not recovered", "yielded", "own HOLD beyond the fence (fails)",
                            "own RTL/LAND path beyond the fence (reported)",
                            "autopilot's own worst m (< 0 inside)", "closest approach m",
                            "median clearance m"], out)  # fmt: skip
    finite = [r for r in rows if math.isfinite(r["min_clearance_m"])]
    near = sorted(finite, key=lambda r: r["min_clearance_m"])[:10]
    closest = markdown_table(
        ["drill", "airframe", "clearance m", "first reason", "yielded to"],
        [[r["drill"], r["airframe"], r["min_clearance_m"], r["first_reason"][:50] or "-",
          r["yielded"] or "-"] for r in near],
    )  # fmt: skip
    breaches = _flag_sum(rows, "breach")
    overrides = sum(int(r["overridden"]) for r in rows)
    failed = failed_drills(rows)
    stuck = _flag_sum(rows, "not_recovered")
    unjudged = sum(r.get("end_mode") in ("fallback", "pid") and not r["yielded"]
                   and not _flag(r, "not_recovered") for r in rows)  # fmt: skip
    own = sum(_own_counts(r) for r in rows)
    crashed = sum(r["kind"] == "crash" for r in rows)  # unjudged: never a pass
    path = sum(_own_path(r) for r in rows)
    first: dict[str, int] = {}
    for r in rows:
        if not drill_passed(r):
            name = r.get("failed_check") or "?"
            first[name] = first.get(name, 0) + 1
    named = ", ".join(f"{k} {v}" for k, v in sorted(first.items())) or "none"
    totals = (f"{len(rows)} drills judged by safety.judge; ground-truth breaches beyond the "
              f"tolerance: {breaches}; overridden autopilot failsafes: {overrides}; the "
              f"autopilot's own HOLD after a yield beyond the fence: {own}; its own RTL/LAND "
              f"path beyond the fence (reported, not failing): {path}; crashed drills: "
              f"{crashed}; not recovered (the net still flying at the end of a drill judged on "
              f"it): {stuck}; ended in the net's fallback/PID, not judged on it: {unjudged}; "
              f"drills failing a check (first failed: {named}): {failed}; exit 1 on drills "
              f"failing a check, crashes included = {failed}")  # fmt: skip
    return table, closest, totals, failed


def bounds(rows: list[dict], target: float = TARGET_BOUND) -> str:
    """Per airframe and per kind: drills, breaches (a crash counts as one: not judged), the
    one-sided 95 % Clopper–Pearson upper bound on the breach probability, and how many more
    breach-free drills would bring it to `target`; then the drills `target` needs in all."""
    need = drills_needed(target)
    keys = sorted({(r["airframe"], r["kind"]) for r in rows if r["kind"] != "crash"})
    keys += [(a, "all") for a in sorted({r["airframe"] for r in rows})]
    out = []
    for a, k in keys:
        rs = [r for r in rows if r["airframe"] == a and (k == "all" or r["kind"] in (k, "crash"))]
        if k != "all":  # a crashed drill counts against its own kind (its index says which)
            rs = [r for r in rs if r["kind"] == k or _crash_kind(r) == k]
        n, b = len(rs), sum(_flag(r, "breach") or r["kind"] == "crash" for r in rs)
        ub = breach_upper_bound(b, n)
        more = max(0, need - n) if b == 0 else "-"
        out.append([a, k, n, b, f"{ub:.2e}", more])
    table = markdown_table(["airframe", "kind", "drills", "breaches",
                            f"breach probability ≤ ({100 * CONFIDENCE:.0f} %, Clopper–Pearson)",
                            f"more breach-free drills for ≤ {target:g}"], out)  # fmt: skip
    return (f"{table}\n\nA breach-free campaign bounds the breach probability at {target:g} "
            f"({100 * CONFIDENCE:.0f} % one-sided) after {need:,} drills (1 − 0.05^(1/n) ≤ "
            f"{target:g}); each kind alone needs as many.")  # fmt: skip


def _crash_kind(r: dict) -> str:
    """A crashed drill's kind, from its index (the kinds in turn, safety.campaign)."""
    try:
        return drill_kind(r["airframe"], drill_index(r["drill"]))
    except (ValueError, IndexError, KeyError):
        return ""


def _flag(r: dict, key: str) -> bool:
    """A boolean column, also as read back from metrics.csv ("True" / "False" / "")."""
    v = r.get(key, False)
    return v if isinstance(v, bool) else str(v) == "True"


def _flag_sum(rows: list[dict], key: str) -> int:
    return sum(_flag(r, key) for r in rows)


def _own(r: dict) -> tuple[float, str] | None:
    """(the autopilot's own worst excursion after a yield [m], its mode there), or None."""
    x = r.get("autopilot_excursion_m")
    if x in ("", None) or not math.isfinite(float(x)):
        return None
    return float(x), str(r.get("autopilot_excursion_mode", ""))


def _own_counts(r: dict) -> bool:
    """The autopilot's own flight beyond the fence in a mode that must fit it (its HOLD)."""
    o = _own(r)
    return o is not None and o[0] > r.get("_tol", 0.0) and o[1] not in FAILSAFE_PATH_MODES


def _own_path(r: dict) -> bool:
    """The autopilot's own RTL / LAND path beyond the fence: reported, not failing."""
    o = _own(r)
    return o is not None and o[0] > r.get("_tol", 0.0) and o[1] in FAILSAFE_PATH_MODES
