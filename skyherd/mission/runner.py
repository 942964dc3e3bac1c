"""One flight of the companion, from its open links to companion.json: `fly_vehicle` (one vehicle,
lockstep or free-running) and `fly_formation` (K vehicles in lockstep, one link each). Either
runs the loop (mission.companion) under the companion's signals (mission.handover: a signal
hands the vehicles to their autopilots), closes every link and record, writes companion.json
(mission.outcome) and returns (exit code, why it failed): 0 completed, 1 aborted, 128 + the
signal when interrupted.
"""

from __future__ import annotations

import json
import select
import signal
import sys
from pathlib import Path

from skyherd.mission.connect import say
from skyherd.mission.handover import StopRequest, signal_name, stop_on_signals
from skyherd.mission.outcome import write_fleet_outcome, write_outcome
from skyherd.runio import CsvWriter, JsonlWriter, UsageError, cut_records, ports

GO_PATIENCE_S = 120.0
"""--wait-go: how long [s of wall time] the companion waits for its go."""


def wait_go(stream=None, patience_s: float = GO_PATIENCE_S) -> None:
    """Block until a line arrives on `stream` (standard input: how `skyherd fly` starts the flight
    once its recorder listens); EOFError when it is closed first, TimeoutError when nothing comes
    within `patience_s` of wall time."""
    stream = sys.stdin if stream is None else stream
    ready, _, _ = select.select([stream], [], [], patience_s)
    if not ready:
        raise TimeoutError(f"--wait-go: no go on standard input within {patience_s:.0f} s")
    if not stream.readline():
        raise EOFError("--wait-go: standard input closed before the go "
                       "(did the `skyherd fly` that started this companion stop?)")  # fmt: skip


def _progress():
    """The flight's progress on stderr: its phase, ticks, wall time and tick time."""
    from tqdm import tqdm

    return tqdm(total=None, desc="connect", file=sys.stderr, leave=True, mininterval=0.5,
                bar_format="{desc}: {n} ticks, {elapsed} wall {postfix}")  # fmt: skip


def _fly(mission, loop, close, go: bool, aborted):
    """`loop(stop)` under the companion's signals, after the go with `go`; `close()` on every
    way out. An exception aborts the mission (`aborted(e)`: the error and the reason in words),
    a signal interrupts it. Returns (tick stats or None, error, interrupted, the stop request)."""
    error, stats, interrupted = "", None, False
    stop = StopRequest()
    try:
        with stop_on_signals(stop):
            if go:
                wait_go()
            stats = loop(stop)
    except Exception as e:  # noqa: BLE001 - the flight ends; say why, keep what was recorded
        error, reason = aborted(e)
        mission.outcome, mission.reason = "aborted", reason
    except KeyboardInterrupt as e:
        error, interrupted = f"interrupted ({signal_name(e)})", True
        mission.outcome, mission.reason = "interrupted", error
    finally:
        close()
    if stats is not None and stats.handover is not None:  # a signal: handed over, then ended
        error, interrupted = (
            f"interrupted ({signal_name(stop)}): {'; '.join(stats.handover)}",
            True,
        )
        mission.outcome, mission.reason = "interrupted", error
    return stats, error, interrupted, stop


def _ended(mission, error: str, interrupted: bool, stop: StopRequest) -> int:
    """Say the error; the exit code."""
    if error:
        say(f"skyherd companion: {'' if interrupted else 'aborted: '}{error}")
    if mission.outcome == "completed":
        return 0
    return 128 + (stop.signum or signal.SIGINT) if interrupted else 1


def _abort_text(e: Exception) -> tuple[str, str]:
    error = f"{type(e).__name__}: {e}" if not str(e).startswith(type(e).__name__) else str(e)
    return error, str(e)


def fly_vehicle(mission, link, run_dir: Path, frames=None, session=None, lockstep: bool = True,
                go: bool = False) -> tuple[int, str]:  # fmt: skip
    """Fly `mission` (mission.build) over the autopilot's `link` (connect.open_link), with the
    camera's `frames` on `session` (connect.open_camera) or none; ticking on the vehicle's
    marks (`lockstep`) or on the autopilot's clock. Returns (exit code, error)."""
    from skyherd.mission.companion import CompanionParams, run
    from skyherd.mission.vehicle import VehicleLink

    v = VehicleLink(link)
    bar = _progress()
    shown = {"phase": "connect"}

    def on_tick(veh):
        mission.write_track(veh)
        mission.authority.record(veh)  # the changes outside the net's loop (take-off, landing)
        if shown["phase"] != mission.phase:
            shown["phase"] = mission.phase
            bar.set_description_str(mission.phase, refresh=False)
        bar.set_postfix_str(f"t = {veh.t:.1f} s", refresh=False)
        bar.update()

    def loop(stop):
        params = CompanionParams(lockstep=lockstep)
        return run(v, mission, mission.run(v), frames, params, on_tick, stop)

    def close():
        bar.close()
        mission.write_track(v)
        link.close()
        sub = getattr(getattr(frames, "source", None), "sub", None)
        if sub is not None:  # its callbacks end before the session does
            sub.close()
        if session is not None:
            session.close()

    writers = [mission.rec.decisions, mission.rec.track, getattr(mission.net, "events", None)]
    stats, error, interrupted, stop = _fly(mission, loop, close, go, _abort_text)
    err = link.tlog_error
    cut = cut_records(writers) + (
        [{"file": "telemetry.tlog", "error": err, "dropped": None}] if err else []
    )
    write_outcome(run_dir, mission, stats, frames, cut, link)
    return _ended(mission, error, interrupted, stop), error


def load_formation(plan_file: str, cell_m: float):
    """The formation's plan (plan_K<K>.json of `skyherd train sql`), its parameters and the
    vehicles' homes; ValueError with a one-line reason."""
    from skyherd.flight.geo import DEFAULT_HOME
    from skyherd.mission.formation_plan import FormationParams, PlanError, load_plan, vehicle_homes

    try:
        K = len(json.loads(Path(plan_file).read_text(encoding="utf-8")))
        plan = load_plan(plan_file, K)
        params = FormationParams(cell_m=cell_m)
    except (OSError, ValueError, TypeError) as e:  # PlanError is a ValueError
        kind = "plan" if not isinstance(e, ValueError) or isinstance(e, PlanError) else "formation"
        raise ValueError(f"{kind}: {e}; pass a plan_K<K>.json from `skyherd train sql`") from None
    return plan, params, vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)


def fly_formation(plan, params, homes, run_dir: Path, instance: int, key_file: str | None,
                  go: bool = False) -> tuple[int, str]:  # fmt: skip
    """K vehicles (instances `instance`..: mission.formation_plan.vehicle_instances) in lockstep,
    one link each (mission.formation), their telemetry in uav<k>/; UsageError when a link does
    not open. Returns (exit code, error)."""
    from skyherd.flight.geo import DEFAULT_HOME
    from skyherd.hil.link import LinkError, MavlinkLink
    from skyherd.mission.companion import CompanionParams, run_fleet
    from skyherd.mission.formation import FleetRecord, FormationMission
    from skyherd.mission.formation_plan import (
        TRACK_COLUMNS,
        field_offsets,
        plan_ne,
        vehicle_instances,
    )
    from skyherd.mission.vehicle import VehicleLink
    from skyherd.runio.constants import COMPANION_COMPONENT

    K = len(plan)
    events = JsonlWriter(run_dir / "events.jsonl")
    record = FleetRecord(JsonlWriter(run_dir / "decisions.jsonl"),
                         CsvWriter(run_dir / "metrics.csv", TRACK_COLUMNS))  # fmt: skip
    mission = FormationMission(plan_ne(plan, params.cell_m), field_offsets(DEFAULT_HOME, homes),
                               params, record, events)  # fmt: skip
    instances = vehicle_instances(instance, K)
    links = []
    try:
        for k in range(K):
            inst = instances[k]
            (run_dir / f"uav{k}").mkdir(exist_ok=True)
            links.append(MavlinkLink.open(ports.companion_address(inst), source_system=1 + inst,
                                          source_component=COMPANION_COMPONENT,
                                          tlog=run_dir / f"uav{k}" / "telemetry.tlog",
                                          signing_key=key_file))  # fmt: skip
    except LinkError as e:
        for link in links:
            link.close()
        raise UsageError(
            f"{e}; is another companion using instances {instances[0]}..{instances[-1]}?"
        ) from None
    vs = [VehicleLink(link, target_system=1 + inst) for link, inst in zip(links, instances)]
    print(f"skyherd companion: formation of {K} (instances {', '.join(map(str, instances))}), "
          f"lockstep; run folder {run_dir}", file=sys.stderr, flush=True)  # fmt: skip
    bar = _progress()

    def on_tick(vs_):
        mission.write_track(vs_)
        bar.set_description_str(mission.phase, refresh=False)
        bar.set_postfix_str(f"t = {vs_[0].t:.1f} s", refresh=False)
        bar.update()

    def close():
        bar.close()
        mission.write_track(vs)
        for link in links:
            link.close()
        for w in (events, record.decisions, record.track):
            w.close()

    def loop(stop):
        return run_fleet(vs, mission, mission.run(vs), None, CompanionParams(), on_tick, stop)

    def aborted(e: Exception) -> tuple[str, str]:
        error = str(e) or type(e).__name__
        return error, error

    stats, error, interrupted, stop = _fly(mission, loop, close, go, aborted)
    cut = cut_records([events, record.decisions, record.track])
    write_fleet_outcome(run_dir, mission, record, stats, links, cut)
    return _ended(mission, error, interrupted, stop), error
