"""A readable timeline of a run's decisions (decisions.jsonl, the companion's record format).

One record per pilot decision (docs: helpers' LAYOUT, "Per-decision record"):
`{"t", "vehicle", "pilot", "phi", "proposed": {"pos_ned", "vel_ned", "yaw"}, "certified": {…},
"verdict", "reason", "mode", "autopilot_mode", "explanation": {"module", "reason", "concepts"}?}`

    t = 12.5 s lateral: team 0.31 right of centre → east 4 m/s; net: accepted

Consecutive decisions that say the same (module, action, verdict) are folded into one line
("… ×6 until t = 15.0 s"). Lines that cannot be read are counted and skipped, never fatal.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

_DIRS = (("north", "south"), ("east", "west"), ("descend", "climb"))


def _vector(vel: Any) -> list[float] | None:
    try:
        v = [float(x) for x in vel]
    except (TypeError, ValueError):
        return None
    if len(v) != 3 or not all(math.isfinite(x) for x in v):
        return None
    return v


def describe_velocity(vel: Any) -> str:
    """NED velocity [m/s] → every component that is not ~0, largest first: 'east 4 m/s',
    'east 2.1 m/s, climb 0.58 m/s', or 'hover' (below 0.05 m/s in all)."""
    v = _vector(vel)
    if v is None:
        return "-"
    if math.hypot(*v) < 0.05:
        return "hover"
    parts = []
    for i in sorted(range(3), key=lambda k: -abs(v[k])):
        if abs(v[i]) >= 0.005:
            name = _DIRS[i][0] if v[i] > 0 else _DIRS[i][1]
            parts.append(f"{name} {abs(v[i]):.3g} m/s")
    return ", ".join(parts)


def ned_vector(vel: Any) -> str:
    """NED velocity in full: '(+0.00, +2.10, -0.58) m/s NED', or '-'."""
    v = _vector(vel)
    return "-" if v is None else "(" + ", ".join(f"{x:+.2f}" for x in v) + ") m/s NED"


def _setpoint(rec: dict, key: str) -> str:
    sp = rec.get(key) or {}
    if not isinstance(sp, dict):
        return "-"
    if sp.get("vel_ned") is not None:
        return describe_velocity(sp["vel_ned"])
    if sp.get("pos_ned") is not None:
        try:
            return "to (" + ", ".join(f"{float(x):.1f}" for x in sp["pos_ned"]) + ") m"
        except (TypeError, ValueError):
            return "-"
    return "-"


@dataclass
class Decision:
    t: float
    who: str  # module name, or the pilot when there is no explanation
    why: str
    action: str
    verdict: str
    net: str  # the safety net's part: 'accepted', 'projected → east 2.1 m/s (…)', …
    concepts: dict[str, float]
    record: dict


def parse_record(rec: dict) -> Decision:
    t = float(rec["t"])
    ex = rec.get("explanation") if isinstance(rec.get("explanation"), dict) else None
    proposed, certified = _setpoint(rec, "proposed"), _setpoint(rec, "certified")
    verdict = str(rec.get("verdict", "?"))
    net = verdict
    if verdict != "accepted" and certified not in ("-", proposed):
        net += f" → {certified}"
    if verdict not in ("accepted", "none") and rec.get("reason"):
        net += f" ({rec['reason']})"
    if ex is not None:
        who, why = str(ex.get("module", "?")), str(ex.get("reason", ""))
        concepts = {str(k): v for k, v in (ex.get("concepts") or {}).items()}
    else:
        who, why, concepts = str(rec.get("pilot", "?")), "no explanation recorded", {}
    return Decision(t, who, why, proposed, verdict, net, concepts, rec)


def read_decisions(path: Path) -> tuple[list[Decision], int]:
    """(decisions in file order, number of unreadable lines)."""
    out, bad = [], 0
    with open(path, encoding="utf-8", errors="replace") as f:
        for line in f:
            if not line.strip():
                continue
            try:
                rec = json.loads(line)
                out.append(parse_record(rec))
            except (ValueError, KeyError, TypeError):
                bad += 1  # a torn last line after a kill, or a foreign record
    return out, bad


def line(d: Decision) -> str:
    return f"t = {d.t:.1f} s {d.who}: {d.why} → {d.action}; net: {d.net}"


def timeline(decisions: list[Decision]) -> list[str]:
    """One line per run of decisions with the same module, action and verdict."""
    lines: list[str] = []
    i = 0
    while i < len(decisions):
        d = decisions[i]
        j = i
        while j + 1 < len(decisions) and (
            decisions[j + 1].who,
            decisions[j + 1].action,
            decisions[j + 1].verdict,
        ) == (d.who, d.action, d.verdict):
            j += 1
        s = line(d)
        if j > i:
            s += f"  (×{j - i + 1} until t = {decisions[j].t:.1f} s)"
        lines.append(s)
        i = j + 1
    return lines


def at_time(decisions: list[Decision], t: float) -> Decision | None:
    """The decision in force at time t: the last one at or before t (else the first)."""
    if not decisions:
        return None
    before = [d for d in decisions if d.t <= t + 1e-9]
    return before[-1] if before else decisions[0]


def detail(d: Decision) -> list[str]:
    out = [line(d)]
    for k, v in d.concepts.items():
        out.append(f"    {k} = {v}")
    r = d.record
    ex = r.get("explanation") if isinstance(r.get("explanation"), dict) else {}
    q = ex.get("q_values")
    if isinstance(q, dict) and q:
        out.append("    Q: " + ", ".join(f"{k} {v}" for k, v in q.items()))
    for key in ("proposed", "certified"):
        sp = r.get(key) if isinstance(r.get(key), dict) else {}
        if sp.get("vel_ned") is not None:
            out.append(f"    {key} {ned_vector(sp['vel_ned'])}")
    out.append(
        f"    pilot {r.get('pilot', '?')}, mode {r.get('mode', '?')}, autopilot {r.get('autopilot_mode', '?')}"
    )
    return out


def explain(decisions: list[Decision], bad: int, t: float | None, max_lines: int) -> list[str]:
    """What `skyherd explain` prints: the decision in force at time `t` [s] in detail, or
    (t None) the timeline cut at `max_lines`; then the count of decisions, of those explained
    and of the `bad` lines skipped."""
    if t is not None:
        out = detail(at_time(decisions, t))
    else:
        lines = timeline(decisions)
        out = lines[:max_lines]
        if len(lines) > max_lines:
            out.append(f"… {len(lines) - max_lines} more lines (--max-lines)")
    n_ex = sum(1 for d in decisions if d.concepts or d.record.get("explanation"))
    skipped = f", {bad} unreadable lines skipped" if bad else ""
    return [*out, f"{len(decisions)} decisions, {n_ex} explained{skipped}"]
