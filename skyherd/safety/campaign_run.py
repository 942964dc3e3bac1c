"""One campaign drill → its row of the campaign's metrics.csv (`skyherd drill --campaign`).

A drill is a pure function of (airframe, index, seed, constraint set): `run_process_drill`
flies it in the in-process drill loop (safety.drills.run_drill); mission.campaign flies the same
drill through the companion's mission code. Either result becomes one row (`drill_row`) with the
judge's verdict (safety.judge: `passed`, the first failed check) and its figures; a drill that
raised is a failed row (`crash_row`: not judged, never a pass). Keys starting with "_" travel
with the row to the campaign (its events, its track, its fence tolerance) and are not columns.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from skyherd.runio.constants import MISSION_DRILL_INSTANCE
from skyherd.safety.campaign import drill_kind, drill_rng, make_drill, make_vehicle
from skyherd.safety.config import (
    EnvelopeFileError,
    default_envelope_path,
    fill_dataclass,
    load_envelope,
)
from skyherd.safety.drills import DrillParams, run_drill
from skyherd.safety.envelope import EnvelopeSpec
from skyherd.safety.judge import first_failed
from skyherd.safety.supervisor import SupervisorParams

COLUMNS = ["drill", "airframe", "kind", "passed", "failed_check", "min_clearance_m", "breach",
           "overridden", "yielded", "switches", "fallback_s", "pid_s", "autopilot_excursion_m",
           "autopilot_excursion_mode", "first_reason", "why", "constraint_set_version",
           "restored", "end_mode", "not_recovered", "through", "decisions", "sim_s",
           "cpu_s"]  # fmt: skip
"""The campaign's metrics.csv columns, in order."""
PLOT_TRACKS = 400
"""Tracks per airframe the campaign keeps for its plot (the first to finish): a campaign of
10^5 drills keeps 400 tracks in memory, not 10^5."""


@dataclass(frozen=True)
class DrillJob:
    """One campaign drill to fly (picklable: it goes to a worker process or a Ray task)."""

    airframe: str
    index: int
    """The drill's index: its kind (the airframe's kinds in turn) and its random stream."""
    seed: int
    """The campaign's seed."""
    envelope: Path | None = None
    """The constraint-set file; None: the airframe's field set."""
    through: str = "process"
    """"process": the in-process drill loop; "mission": the companion's mission code."""
    instance: int = MISSION_DRILL_INSTANCE
    """"mission": the first vehicle instance to try (each drill at once takes the next free)."""


class EventSink:
    """Keeps the safety events a drill writes (the campaign tags them with the drill)."""

    def __init__(self) -> None:
        self.records: list[dict] = []

    def write(self, record: dict) -> None:
        self.records.append(record)


def load_set(airframe: str, envelope: Path | None) -> tuple[EnvelopeSpec, SupervisorParams]:
    """The constraint set and the supervisor's parameters a campaign flies `airframe` with:
    `envelope`, or the airframe's field set. EnvelopeFileError (a ValueError) if the file
    cannot be read; ValueError if its supervisor table is bad or it is another airframe's."""
    path = envelope if envelope is not None else default_envelope_path(airframe)
    try:
        spec, table = load_envelope(path)
        sp = fill_dataclass(SupervisorParams, table, "supervisor")
    except EnvelopeFileError as e:  # what to do, for the command line
        raise EnvelopeFileError(f"{e}; fix the file or pass another --envelope") from e
    except ValueError as e:
        raise ValueError(f"constraint set {path}: {e}") from e
    if spec.airframe != airframe:
        raise ValueError(
            f"constraint set {path} is for {spec.airframe}, not {airframe}; "
            "pass a matching --envelope"
        )
    return spec, sp


def run_process_drill(job: DrillJob) -> dict:
    """One campaign drill in the in-process drill loop (safety.drills.run_drill) → its row."""
    spec, sp = load_set(job.airframe, job.envelope)
    p = DrillParams()
    rng = drill_rng(job.seed, job.airframe, job.index)
    d = make_drill(drill_kind(job.airframe, job.index), job.index, rng, spec, p)
    sink = EventSink()
    r = run_drill(d.script, make_vehicle(d, job.seed), d.spec, sp, p, sink)
    end_mode = ("ai", "fallback", "pid")[int(r.track["mode"][-1])]
    return drill_row(r, job.airframe, d.kind, spec, d.spec, sink, end_mode, r.track["pos"][::10])


def drill_row(r, airframe: str, kind: str, spec: EnvelopeSpec, moved: EnvelopeSpec,
              sink: EventSink, end_mode: str, pos) -> dict:  # fmt: skip
    """A drill's metrics.csv row from its result (safety.drills.DrillResult or
    mission.drill_link.LinkDrillResult): the judge's verdict and figures. `moved`: the drill's
    constraint set (the fixed-wing's fence moved); `pos`: its track, NED [m]. Overridden
    failsafes: the drill's count, at least 1 when the judge's modes check failed (a request
    that crossed a failsafe is counted by the judge from the truth, not by the drill)."""
    failed = first_failed(r.checks)
    ok = {c.name: c.ok for c in r.checks}
    pos = np.asarray(pos, float).reshape(-1, 3)
    return {
        "drill": r.name, "airframe": airframe, "kind": kind, "passed": failed is None,
        "failed_check": "" if failed is None else failed.name,
        "min_clearance_m": round(r.min_clearance_m, 3), "breach": not ok["fence"],
        "overridden": max(r.overridden, int(not ok["modes"])), "yielded": r.yielded,
        "switches": r.switches, "fallback_s": round(r.fallback_s, 2), "pid_s": round(r.pid_s, 2),
        "autopilot_excursion_m": "" if not math.isfinite(r.autopilot_excursion_m)
        else round(r.autopilot_excursion_m, 2),
        "autopilot_excursion_mode": r.autopilot_excursion_mode, "restored": r.restored,
        "first_reason": r.reasons[0] if r.reasons else "", "why": r.why,
        "end_mode": end_mode, "not_recovered": not ok["recovered"],
        "constraint_set_version": spec.version, "_events": sink.records,
        "_tol": moved.limits.breach_tolerance_m,
        "_track": (pos - np.r_[fence_offset(moved, spec), 0.0]).tolist(),
    }  # fmt: skip


def crash_row(job: DrillJob, error: Exception) -> dict:
    """The row of a drill that raised: failed (check "crash"), never judged."""
    return {c: "" for c in COLUMNS} | {
        "drill": f"crashed {job.index:04d}", "airframe": job.airframe, "kind": "crash",
        "passed": False, "failed_check": "crash", "min_clearance_m": math.nan, "breach": False,
        "overridden": 0, "not_recovered": False, "why": f"{type(error).__name__}: {error}",
        "_events": [], "_track": [],
    }  # fmt: skip


_BOOLS = ("passed", "breach", "not_recovered")
_INTS = ("overridden", "switches", "decisions")
_FLOATS = ("min_clearance_m", "fallback_s", "pid_s", "autopilot_excursion_m", "sim_s", "cpu_s")


def row_from_csv(d: dict[str, str], tol: float) -> dict:
    """A metrics.csv row read back (a resumed campaign's) → the row as its drill gave it to the
    verdict: booleans and numbers typed, an empty cell kept empty; `tol`: the drill's fence
    tolerance (its airframe's set; 0 for a crash). ValueError on a cell that is not its type."""
    row: dict = dict(d)
    for k in _BOOLS:
        if d[k] not in ("True", "False"):
            raise ValueError(f"drill {d['drill']!r}: {k} {d[k]!r} is not True/False")
        row[k] = d[k] == "True"
    for k in _INTS:
        row[k] = int(d[k]) if d[k] != "" else ""
    for k in _FLOATS:
        row[k] = float(d[k]) if d[k] != "" else ("" if k != "min_clearance_m" else math.nan)
    row["_tol"] = 0.0 if d["kind"] == "crash" else tol
    return row


def split_row(row: dict) -> tuple[dict, list[dict], tuple[str, list]]:
    """A row as it comes from its drill → (the row for metrics.csv and the verdict, which keeps
    `_tol` (0 for a crash), its safety events tagged with the drill, (its kind, its track))."""
    row.setdefault("_tol", 0.0)
    events = [{"drill": row["drill"], "airframe": row["airframe"], **e} for e in row.pop("_events")]
    return row, events, (row["kind"], row.pop("_track"))


def fence_offset(moved: EnvelopeSpec, base: EnvelopeSpec) -> np.ndarray:
    """How far the drill's fence was moved (fixed-wing) [m], (north, east): tracks are drawn in
    the base set's frame."""
    if not moved.inclusions:
        return np.zeros(2)
    return moved.inclusions[0].points[0] - base.inclusions[0].points[0]
