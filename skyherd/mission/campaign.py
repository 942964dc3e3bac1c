"""The drill campaign's runner (`skyherd drill --campaign N`): N randomized adversarial drills per
airframe (safety.campaign), each a pure function of its job (airframe, index, seed), on this
process, a local process pool or Ray tasks (runio.parallel: a dead worker's drill runs again).

A drill flies `through` "mission" (mission.drill_link: `skyherd fly`'s mission code — the
companion's SingleVehicleMission with the drill's adversarial pilot, the same SafetyNet,
authority and decision records — over loopback MAVLink to the built-in vehicle in lockstep on
the simulation clock, each drill running at once on its own vehicle instance) or "process" (the
in-process drill loop, safety.campaign_run). Either way it becomes one row of the campaign's
metrics.csv (safety.campaign_run.drill_row); the verdict over the rows is
safety.campaign_verdict's.
"""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from skyherd.runio.runfolder import cut_to_whole_lines, filter_jsonl
from skyherd.safety.campaign import drill_index, drill_kind, drill_rng, make_drill
from skyherd.safety.campaign_run import (
    COLUMNS,
    PLOT_TRACKS,
    DrillJob,
    EventSink,
    crash_row,
    drill_row,
    load_set,
    row_from_csv,
    run_process_drill,
    split_row,
)
from skyherd.safety.drills import DrillParams


def campaign_jobs(airframes: list[str], n: int, seed: int, envelope: Path | None,
                  through: str, instance: int) -> list[DrillJob]:  # fmt: skip
    """The campaign's drills 0..n-1 of every airframe, drill by drill (the airframes in turn)."""
    return [DrillJob(a, i, seed, envelope, through, instance) for i in range(n) for a in airframes]


def run_one(job: DrillJob) -> dict:
    """One campaign drill in this process → its row (a plain, picklable dict) with the way it
    flew and its CPU time; a drill that raised is a failed row (one broken drill must not lose
    the campaign)."""
    cpu0 = time.process_time()
    try:
        row = run_mission_drill_row(job) if job.through == "mission" else run_process_drill(job)
        return row | {"through": job.through, "cpu_s": round(time.process_time() - cpu0, 3)}
    except Exception as e:  # noqa: BLE001  one broken drill must not lose the campaign
        return crash_row(job, e)


def run_mission_drill_row(job: DrillJob) -> dict:
    """One campaign drill flown by the companion's mission code (mission.drill_link) → its row."""
    from skyherd.mission.drill_link import run_mission_drill  # MAVLink, only when flown so

    spec, _ = load_set(job.airframe, job.envelope)
    kind = drill_kind(job.airframe, job.index)
    sink = EventSink()
    r = run_mission_drill(kind, job.airframe, job.index, job.seed, job.instance, sink, job.envelope)
    rng = drill_rng(job.seed, job.airframe, job.index)
    moved = make_drill(kind, job.index, rng, spec, DrillParams()).spec
    track = [row[1:] for row in r.track]
    return drill_row(r, job.airframe, kind, spec, moved, sink, r.end_mode, track) | {
        "decisions": r.setpoints,
        "sim_s": round(r.sim_s, 2),
    }


def run_all(jobs: list[DrillJob], workers: int = 1, backend: str = "auto",
            ray_address: str | None = None,
            say: Callable[[str], None] = print) -> Iterator[dict]:  # fmt: skip
    """Every job's row as it finishes: in this process, in order, with one worker and no Ray
    address; else on Ray tasks or a process pool (runio.parallel), in completion order."""
    if workers == 1 and ray_address is None:
        yield from map(run_one, jobs)
        return
    from skyherd.runio.parallel import map_unordered

    for _, row in map_unordered(run_one, jobs, backend, workers, ray_address, say=say):
        yield row


def record_campaign(
    jobs: list[DrillJob],
    events,
    metrics,
    workers: int = 1,
    backend: str = "auto",
    ray_address: str | None = None,
    say: Callable[[str], None] = print,
    on_row: Callable[[dict], None] | None = None,
) -> tuple[list[dict], dict[str, list]]:
    """Every job flown (`run_all`) and recorded as it finishes: its safety events to `events`
    (tagged with the drill), its row to `metrics` (safety.campaign_run.COLUMNS), then
    `on_row(row)`; (the rows, each airframe's first PLOT_TRACKS (kind, track) pairs) for the
    verdict and the plot."""
    rows: list[dict] = []
    tracks: dict[str, list] = {j.airframe: [] for j in jobs}
    for row in run_all(jobs, workers, backend, ray_address, say=say):
        row, drill_events, track = split_row(row)
        for e in drill_events:
            events.write(e)
        if len(tracks[row["airframe"]]) < PLOT_TRACKS:
            tracks[row["airframe"]].append(track)
        metrics.write(row)
        rows.append(row)
        if on_row is not None:
            on_row(row)
    return rows, tracks


CAMPAIGN_OPTIONS = ("airframe", "campaign", "campaign_drills", "seed", "envelope", "through",
                    "target_bound")  # fmt: skip
"""The options that define a campaign (config.json's "args"): a resumed one flies them as the
folder's first sitting gave them."""


def judged_rows(folder: Path, tols: dict[str, float]) -> list[dict]:
    """The rows an interrupted campaign's folder holds (metrics.csv cut back to its last whole
    row: a kill mid-write), typed as their drills gave them (safety.campaign_run.row_from_csv;
    `tols`: each airframe's fence tolerance); events.jsonl keeps only those drills' events (a
    drill with no row flies again and writes its events again). ValueError if metrics.csv is
    not a campaign's of this version (its columns) or a row cannot be read."""
    metrics = folder / "metrics.csv"
    if not metrics.exists():
        return []
    cut_to_whole_lines(metrics)
    with open(metrics, newline="", encoding="utf-8") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is not None and reader.fieldnames != COLUMNS:
            raise ValueError(f"{metrics}: its columns are not a campaign's of this version")
        rows = [row_from_csv(d, tols.get(d["airframe"], 0.0)) for d in reader]
    judged = {(r["airframe"], r["drill"]) for r in rows}
    events = folder / "events.jsonl"
    if events.exists():
        cut_to_whole_lines(events)
        filter_jsonl(events, lambda e: (e.get("airframe"), e.get("drill")) in judged)
    return rows


def jobs_left(jobs: list[DrillJob], rows: list[dict]) -> list[DrillJob]:
    """The jobs of a campaign that have no row yet (each drill is judged once)."""
    done = {(r["airframe"], drill_index(r["drill"])) for r in rows}
    return [j for j in jobs if (j.airframe, j.index) not in done]
