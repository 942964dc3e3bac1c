"""How a `skyherd fly` flight ended, said in its summary.md: how the companion ended (a
signal: what it handed to the autopilot), what the autopilot did alone after it (the
simulator's span without the companion, from sim_stats.json), and which records a full disk or
a read-only folder cut; the summary while the flight runs, and the one a child writes when its
`fly` died. The run folder's checks before anything starts are runio.run.open_run_folder; the
signals that end a flight, runio.signals."""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

from skyherd.runio import try_write_text

RUNNING = (
    "# skyherd fly: running\n\n**Running** (or `skyherd fly` was killed: its children then "
    'ended on their parent-death signals, and "How it ended" below says what they did)\n'
)


def write_running(run_dir: Path) -> None:
    """summary.md while the flight runs: what a folder left by a `kill -9` of `fly` says."""
    try_write_text(run_dir / "summary.md", RUNNING)


def parent_died(run_dir: Path, vehicles: list[str] | None = None) -> None:
    """A child whose `skyherd fly` died says how the flight ended in its summary.md."""
    lines = ["`skyherd fly` died; its children ended on their parent-death signals"]
    append_ending(run_dir, lines + ending_lines(run_dir, vehicles))


def report_safely(report, *args, why: str) -> bool:
    """`report(*args)` (True: the flight completed); a report that fails (a full or read-only
    folder, records cut mid-line) is said on stderr with `why`, and counts as not completed."""
    try:
        return bool(report(*args))
    except Exception as e:  # noqa: BLE001 - the ending is still said, in append_ending
        print(f"skyherd fly: the report was not written ({type(e).__name__}: {e}); "
              f"{why or 'the flight ended'}: see how, below", file=sys.stderr, flush=True)  # fmt: skip
        return False


def _json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _last_row(world: Path) -> str:
    """world.csv's last row in words (where the vehicle was when the simulation ended)."""
    try:
        with open(world, newline="") as f:
            rows = list(csv.DictReader(f))
        r = rows[-1]
        return (f"; world.csv ends at t = {float(r['t']):.1f} s: {r['mode']}, "
                f"{'armed' if r['armed'] == '1' else 'disarmed'}, altitude {-float(r['down']):.1f} m")  # fmt: skip
    except (OSError, IndexError, KeyError, ValueError):
        return ""


def _alone(name: str, a: dict | None, last: str = "") -> str:
    """One simulator's span without the companion, in words."""
    if not a:
        return f"{name}: no span alone recorded (the simulator was stopped or killed){last}"
    alt = a.get("altitude_m", math.nan)
    alt = abs(alt) if abs(alt) < 0.05 else alt
    if a["span_s"] == 0 and not a["armed"]:
        return (f"{name}: the vehicle was disarmed when the companion ended (t = {a['t_gone_s']:.1f} s): "
                f"{a['mode']}, altitude {alt:.1f} m")  # fmt: skip
    steps = " → ".join(f"{m['mode']}{'' if m['armed'] else ' (disarmed)'} at {m['t']:.1f} s"
                       for m in a.get("modes", []))  # fmt: skip
    state = "armed" if a["armed"] else "disarmed"
    return (f"{name}: the autopilot alone from t = {a['t_gone_s']:.1f} s for {a['span_s']:.1f} s "
            f"of simulation time ({a['ended']}): {steps}; at the end {a['mode']}, {state}, "
            f"altitude {alt:.1f} m")  # fmt: skip


def stats_from_output(lines: list[str]) -> dict[str, dict]:
    """The simulators' final stats from their output (`skyherd sim` prints them last, as
    `{json}` or, one per vehicle of a fleet, `uav<k> {json}`): the copy `fly` keeps in memory
    when sim_stats.json could not be written."""
    out = {}
    for ln in lines:
        name, _, rest = ln.partition(" ") if not ln.startswith("{") else ("sim", "", ln)
        try:
            stats = json.loads(rest)
        except ValueError:
            continue
        if isinstance(stats, dict) and "after_companion" in stats:
            out[name] = stats
    return out


def recording_cut(recorder) -> list[dict]:
    """flight.mcap's cut (`fly`'s own recorder, record.flight_recording.FlightRecording), as `cut_records` says."""
    log = getattr(getattr(recorder, "recorder", None), "log", None)
    err = getattr(getattr(log, "file", None), "error", None)
    return [{"file": "flight.mcap", "error": err, "dropped": log.errors}] if err else []


def ending_lines(run_dir: Path, vehicles: list[str] | None = None,
                 output: list[str] | None = None, cut: list[dict] | None = None) -> list[str]:  # fmt: skip
    """The "How it ended" lines. `vehicles`: the formation's uav<k> sub-folders (None: one
    vehicle, its files in run_dir). `output`: the simulators' output lines `fly` kept; `cut`:
    the records `fly` itself cut (its recording)."""
    kept = stats_from_output(output or [])
    comp = _json(run_dir / "companion.json")
    lines = []
    if comp:
        outcome, reason = comp.get("outcome"), comp.get("reason") or ""
        said = reason if reason.startswith(str(outcome)) else f"{outcome}: {reason}".rstrip(": ")
        lines.append(f"companion: {said}")
    else:
        lines.append("companion: wrote no companion.json (killed, or its folder is not writable)")
    cut = [dict(c, where="fly") for c in cut or []]
    cut += [dict(c, where="companion") for c in comp.get("records_cut", [])]
    for name in vehicles or ["sim"]:
        stats = _json(run_dir / name / "sim_stats.json" if vehicles else run_dir / "sim_stats.json")
        stats = stats or kept.get(name, {})
        folder = run_dir / name if vehicles else run_dir
        lines.append(_alone(name, stats.get("after_companion"), _last_row(folder / "world.csv")))
        cut += [dict(c, where=name) for c in stats.get("records_cut", [])]
    for c in cut:
        dropped = "" if c.get("dropped") is None else f", {c['dropped']} records dropped"
        lines.append(f"records cut: {c['file']} ({c['where']}): {c['error']}{dropped}")
    return lines


def append_ending(run_dir: Path, lines: list[str]) -> None:
    """The lines under "## How it ended" at the end of summary.md, and on standard error (the
    verdict stays the last line of standard output); if summary.md cannot be written (a
    read-only folder), on standard output, with the reason on stderr."""
    text = "\n".join(f"- {ln}" for ln in lines)
    path = run_dir / "summary.md"
    try:
        old = path.read_text() if path.exists() else "# skyherd fly\n"
    except OSError:
        old = "# skyherd fly\n"
    why = try_write_text(path, old.rstrip() + "\n\n## How it ended\n\n" + text + "\n")
    if why is None:  # the page of the whole flight, from the summary as it now stands
        from skyherd.report.page import write_report_html

        write_report_html(run_dir)
    try:  # a simulator whose `fly` died: nobody reads its output
        print("How it ended:\n" + text, file=sys.stderr if why is None else sys.stdout, flush=True)
        if why is not None:
            print(f"skyherd fly: {why}; how the flight ended is above", file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def end_run(run_dir: Path, report, *args, why: str, sims, vehicles=None, recorder=None) -> bool:
    """After a flight: `report(run_dir, *args)` (report_safely), then "How it ended" from the
    simulators `sims` (runio.launch children: their output kept in memory), the `vehicles`
    (ending_lines) and `fly`'s `recorder` (its cut); True: the flight completed."""
    ok = report_safely(report, run_dir, *args, why=why)
    output = [ln for c in sims for ln in (c.lines or ())]
    append_ending(run_dir, ending_lines(run_dir, vehicles, output, recording_cut(recorder)))
    return ok


def make_plots(run_dir: Path, plots: list) -> None:
    """The report's plots, (file name, call) each, after the verdict is printed: matplotlib
    (its import and drawing) is off the way to the verdict; then report.html again, with them.
    A plot that fails is said on stderr; the flight's verdict and exit code stand."""
    for name, plot in plots:
        try:
            plot()
        except Exception as e:  # noqa: BLE001 - a plot never changes how the flight ended
            print(f"skyherd fly: {name} was not made ({type(e).__name__}: {e})", file=sys.stderr,
                  flush=True)  # fmt: skip
    if plots:
        from skyherd.report.page import write_report_html

        write_report_html(run_dir)
