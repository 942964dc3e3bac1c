"""A formation run folder read back (`skyherd fly --mission formation`): every vehicle's track
from metrics.csv (the companion's TRACK_COLUMNS, field frame) and every vehicle judged by
safety.judge as `skyherd fly` judges one."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from skyherd.flight.geo import DEFAULT_HOME
from skyherd.mission.formation_plan import (
    FormationParams,
    field_offsets,
    formation_envelope,
    plan_ne,
    vehicle_homes,
)
from skyherd.safety.judge import Check, Ending, Truth, judge


def read_tracks(run_dir: Path, K: int) -> list[np.ndarray]:
    """metrics.csv → per vehicle (t, north, east, down) rows in the field frame."""
    tracks: list[list[tuple[float, ...]]] = [[] for _ in range(K)]
    path = run_dir / "metrics.csv"
    if path.exists():
        with open(path, newline="") as f:
            for r in csv.DictReader(f):
                try:
                    k = int(r["vehicle"])
                    row = (float(r["t"]), float(r["north"]), float(r["east"]), float(r["down"]))
                except (KeyError, TypeError, ValueError):  # TypeError: a field is missing
                    continue  # a torn last line of a killed companion
                if 0 <= k < K:
                    tracks[k].append(row)
    return [np.array(t) if t else np.zeros((0, 4)) for t in tracks]


def judge_vehicles(run_dir: Path, plan, params: FormationParams, comp: dict) -> list[list[Check]]:
    """safety.judge on each vehicle, as `skyherd fly` judges one: its truth (uav<k>/world.csv,
    moved from its home into the field frame) against the formation's envelope, the net's
    switches (events.jsonl), the AI window from its hand-over to the settled formation's
    landing, no camera, the mission's outcome (`comp`: the companion's companion.json). The
    formation writes no modes.jsonl: its modes check sees no changes. One list of checks per
    vehicle."""
    K = len(plan)
    paths = plan_ne(plan, params.cell_m)
    spec = formation_envelope(list(paths), params)
    homes = vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)
    off = field_offsets(DEFAULT_HOME, homes)
    events = []
    try:
        for line in (run_dir / "events.jsonl").read_text().splitlines():
            try:
                events.append(json.loads(line))
            except ValueError:
                pass  # a line cut by a kill
    except OSError:
        pass
    t_end = (comp.get("times") or {}).get("all_over_targets")
    ending = Ending(comp.get("outcome", "aborted"), str(comp.get("reason") or ""))
    out = []
    for k in range(K):
        rows = []
        try:
            with open(run_dir / f"uav{k}" / "world.csv", newline="") as f:
                rows = list(csv.DictReader(f))
        except OSError:
            pass
        truth = Truth.from_rows(rows)
        truth = Truth(truth.t, truth.pos_ned + np.r_[off[k], 0.0], truth.armed, truth.mode)
        mine = [e for e in events if e.get("vehicle") == f"uav{k}"]
        start = next((float(e["t"]) for e in mine if e.get("event") == "handover"), None)
        last = float(truth.t[-1]) if len(truth.t) else start
        window = None if start is None else (start, float(t_end) if t_end is not None else last)
        switches = [(float(e["t"]), str(e["to"])) for e in mine if e.get("event") == "switch"]
        out.append(judge(truth, spec, [], window, None, 0, ending, switches))
    return out
