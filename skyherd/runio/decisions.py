"""decisions.jsonl: the per-decision record of LAYOUT.md, one JSON object per pilot decision,
appended and flushed per record (a kill leaves every decision already made).

    {"t": sim s, "vehicle": "uav0", "pilot": "policy|pid|orbit|formation|square",
     "phi": [8 floats] or null, "proposed": {"pos_ned", "vel_ned", "yaw"},
     "certified": {same keys}, "verdict": "accepted|projected|rejected|fallback|pid",
     "reason": "text", "mode": "ai|fallback|pid", "autopilot_mode": "OFFBOARD|HOLD|...",
     "explanation": {...} (optional)}

Strict JSON: NaN and ±inf are written as null (a JSON reader would reject NaN).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from skyherd.runio.runfolder import strict_json
from skyherd.runio.space import Appender

KEYS = ("t", "vehicle", "pilot", "phi", "proposed", "certified", "verdict", "reason", "mode",
        "autopilot_mode")  # fmt: skip
# the net's verdicts, and "none": no net judged it (a learner's evaluation episode flies without)
VERDICTS = ("accepted", "projected", "rejected", "fallback", "pid", "none")
COMMAND_KEYS = ("pos_ned", "vel_ned", "yaw")


def normalise(record: dict[str, Any]) -> dict[str, Any]:
    """The record with every LAYOUT key present (missing → null; commands get all three keys).
    A record without a finite t or with an unknown verdict raises ValueError."""
    rec = strict_json(dict(record))
    t = rec.get("t")
    if not isinstance(t, int | float) or isinstance(t, bool):
        raise ValueError(f"decision record needs a finite sim time t [s], got {record.get('t')!r}")
    if rec.get("verdict") not in VERDICTS:
        raise ValueError(f"decision verdict must be one of {VERDICTS}, got {rec.get('verdict')!r}")
    for k in KEYS:
        rec.setdefault(k, None)
    for k in ("proposed", "certified"):
        if rec[k] is not None:
            rec[k] = {c: rec[k].get(c) for c in COMMAND_KEYS} | {
                c: v for c, v in rec[k].items() if c not in COMMAND_KEYS
            }
    return rec


class DecisionLog:
    """Append-only decisions.jsonl; counts decisions by verdict and keeps the reasons."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        self.appender = Appender(self.path)  # cut by a full disk (runio.space), never raises
        self.counts: dict[str, int] = {}
        self.reasons: dict[str, int] = {}  # reason of non-accepted decisions → count

    def write(self, record: dict[str, Any]) -> dict[str, Any]:
        rec = normalise(record)
        self.appender.write(json.dumps(rec, sort_keys=True, allow_nan=False) + "\n")
        v = rec["verdict"]
        self.counts[v] = self.counts.get(v, 0) + 1
        if v != "accepted" and rec.get("reason"):
            self.reasons[rec["reason"]] = self.reasons.get(rec["reason"], 0) + 1
        return rec

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def close(self) -> None:
        self.appender.close()


def read_decisions(path: Path | str) -> list[dict[str, Any]]:
    """Every complete record of a decisions.jsonl (a line cut by a kill is skipped)."""
    out = []
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return out
