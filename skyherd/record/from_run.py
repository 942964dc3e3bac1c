"""flight.mcap from what a run folder already holds (any command's: fly, companion, sim, drill).

    mcap_from_run(folder)          → folder/flight.mcap
    mcap_from_run(companion_folder, also=[sim_folder])   a flight split over two programs

Read, each only if present:
  metrics.csv / world.csv  rows with t, north, east, down [m] → /<vehicle>/pose; columns
                           ugv<i>_n, ugv<i>_e [m] → /ugvs
  decisions.jsonl          → /<vehicle>/decision, /<vehicle>/phi, /<vehicle>/setpoint
  events.jsonl             records with a time "t" → /<vehicle>/safety/event and /<vehicle>/log
  config.json              an envelope file named under "envelope" (a path, or {"path": ...} /
                           {"file": {"path": ...}}) → /geometry, when safety can read it
Lines that do not parse are skipped and counted (`FromRun.skipped`). Times are the files'
simulation times, so a converted file lines up with one recorded live.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skyherd.record.mcap_file import FlightRecorder


@dataclass
class FromRun:
    path: Path
    counts: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)


def _float(row: dict, key: str) -> float | None:
    try:
        v = float(row[key])
    except (KeyError, TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _rows(path: Path):
    with open(path, newline="", encoding="utf-8") as f:
        yield from csv.DictReader(f)


def _jsonl(path: Path, skipped: dict[str, int]):
    with open(path, encoding="utf-8") as f:
        for line in f:
            try:
                rec = json.loads(line)
                if not isinstance(rec, dict):
                    raise ValueError
                yield rec
            except ValueError:
                skipped[path.name] = skipped.get(path.name, 0) + 1


def _envelope_path(folder: Path) -> Path | None:
    try:
        cfg = json.loads((folder / "config.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    env = cfg.get("envelope")
    if isinstance(env, dict):
        env = env.get("path") or (env.get("file") or {}).get("path") or env.get("source")
    if isinstance(env, str) and Path(env).is_file():
        return Path(env)
    return None


def _csv_items(path: Path, vehicle: str, skipped: dict[str, int]):
    for row in _rows(path):
        t = _float(row, "t")
        if t is None:
            skipped[path.name] = skipped.get(path.name, 0) + 1
            continue
        p = [_float(row, k) for k in ("north", "east", "down")]
        if None not in p:
            yield t, 0, lambda rec, t=t, p=p: rec.pose(t, p, vehicle=vehicle)
        ugvs, i = [], 0
        while f"ugv{i}_n" in row:
            n, e = _float(row, f"ugv{i}_n"), _float(row, f"ugv{i}_e")
            if n is not None and e is not None:
                ugvs.append({"id": i, "pos_ned": [n, e, 0.0]})
            i += 1
        if ugvs:
            yield t, 1, lambda rec, t=t, u=ugvs: rec.ugvs(t, u)


def _timed(rec: dict) -> float | None:
    t = rec.get("t")
    return float(t) if isinstance(t, int | float) and math.isfinite(t) else None


def _folder_items(folder: Path, vehicle: str, skipped: dict[str, int]):
    """(t, order, write) for everything the folder holds; written in time order so that the
    setpoint arrows start at the pose of their time."""
    for name in ("metrics.csv", "world.csv"):
        if (folder / name).is_file():
            yield from _csv_items(folder / name, vehicle, skipped)
    if (folder / "decisions.jsonl").is_file():
        for d in _jsonl(folder / "decisions.jsonl", skipped):
            if (t := _timed(d)) is not None:
                v = str(d.get("vehicle", vehicle))
                yield t, 2, lambda rec, t=t, d=d, v=v: rec.decision(t, d, vehicle=v)
    if (folder / "events.jsonl").is_file():
        for ev in _jsonl(folder / "events.jsonl", skipped):
            if (t := _timed(ev)) is not None:
                yield t, 3, lambda rec, t=t, ev=ev: rec.event(t, ev, vehicle=vehicle)


def mcap_from_run(folder: Path | str, out: Path | str | None = None, *, also: list[Any] = (),
                  vehicle: str = "uav0") -> FromRun:  # fmt: skip
    """Write `out` (default folder/flight.mcap) from the run folder `folder` and the folders in
    `also` (e.g. the simulator's, for the UGVs); returns what was written."""
    folder = Path(folder)
    out = Path(out) if out is not None else folder / "flight.mcap"
    res = FromRun(out)
    rec = FlightRecorder(out, metadata={"source": str(folder), "vehicle": vehicle})
    try:
        env = _envelope_path(folder)
        if env is not None:
            try:
                from skyherd.safety.config import (
                    load_envelope,  # imported only when a file is named
                )

                rec.geometry(0.0, load_envelope(env)[0])
            except (ImportError, ValueError):
                res.skipped["envelope"] = 1
        items = [
            it for f in [folder, *map(Path, also)] for it in _folder_items(f, vehicle, res.skipped)
        ]
        for _, _, write in sorted(items, key=lambda it: (it[0], it[1])):
            write(rec)
    finally:
        rec.close()
    res.counts = dict(rec.counts)
    return res
