"""`skyherd drill --campaign N`: N randomized adversarial drills per airframe (safety.campaign),
seeded, on this process, a local process pool or Ray tasks (`--workers`, `--backend`,
`--ray-address`: runio.parallel; a dead worker's drill runs again, each drill's row is written
as it finishes, and a drill is a pure function of (airframe, index, seed)).

`--through mission` (the default): each drill is `skyherd fly`'s mission code — the companion's
SingleVehicleMission with the drill's adversarial pilot, the same SafetyNet, authority and
decision records — over real loopback MAVLink to the built-in vehicle in lockstep on the
simulation clock (mission.drill_link; each drill running at once on its own vehicle instance
from `--instance`); `--through process`: the in-process drill loop (safety.drills.run_drill).

Writes a run folder: config.json, metrics.csv (one row per drill, flushed as drills finish),
events.jsonl (every switch, yield and parameter verdict, tagged with the drill), campaign.png
(closest approach per drill and kind), summary.md (the tables and the closest approaches).

Every drill is judged by safety.judge (safety.drills.judge_drill: the checks of `skyherd fly`
and a drill's own, `failed_check` names the first that failed). Exit rule (`summarize`): exit 1
when any drill failed a check or crashed (not judged, never a pass). The table counts the
checks' terms: breaches (fence: the net's flight, ground truth up to the stopping time +
RUN_ON_S after a yield), overridden failsafes (modes), the autopilot's own HOLD beyond the fence
after a yield (failsafe: the built-in vehicle fits its HOLD to the uploaded fence), not recovered
(recovered). The autopilot's own RTL / LAND path after a yield (PX4's RTL flies straight home
and does not route around a fence; the net must not undo it) is reported in its own column and
fails no check: it is the autopilot's failsafe, and the fence and home are the mission
planner's to choose so that the line home stays inside.

What the campaign proves (`bounds`): per airframe and per kind, the drills, the breaches and
the one-sided 95 % Clopper–Pearson upper bound on the breach probability (a crash counts as a
breach: it was not judged), and how many breach-free drills a target bound needs
(`--target-bound`, default 1e-3: 2,995).
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import numpy as np

from skyherd.runio.runfolder import RunFolder, markdown_table
from skyherd.safety.judge import FAILSAFE_PATH_MODES, first_failed
from skyherd.scripts.cli import UsageError

COLS = ["drill", "airframe", "kind", "passed", "failed_check", "min_clearance_m", "breach", "overridden",
        "yielded", "switches", "fallback_s", "pid_s", "autopilot_excursion_m",
        "autopilot_excursion_mode", "first_reason", "why", "constraint_set_version",
        "restored", "end_mode", "not_recovered", "through", "decisions", "sim_s",
        "cpu_s"]  # fmt: skip
THROUGH_TEXT = {
    "mission": "the companion's mission code (mission.flight.SingleVehicleMission, DrillPilot) "
    "over loopback MAVLink to the built-in vehicle, lockstep on the simulation clock",
    "process": "the in-process drill loop (safety.drills.run_drill)",
}  # --through
TARGET_BOUND = 1e-3  # --target-bound's default: the breach probability to bound at 95 %


class _Collect:
    def __init__(self):
        self.records = []

    def write(self, r):
        self.records.append(r)


def _load(airframe: str, envelope: Path | None):
    from skyherd.safety.config import (
        EnvelopeFileError,
        default_envelope_path,
        fill_dataclass,
        load_envelope,
    )
    from skyherd.safety.supervisor import SupervisorParams

    path = envelope if envelope is not None else default_envelope_path(airframe)
    try:
        spec, table = load_envelope(path)
        sp = fill_dataclass(SupervisorParams, table, "supervisor")
    except EnvelopeFileError as e:
        raise UsageError(f"{e}; fix the file or pass another --envelope") from e
    except ValueError as e:
        raise UsageError(f"constraint set {path}: {e}") from e
    if spec.airframe != airframe:
        raise UsageError(f"constraint set {path} is for {spec.airframe}, not {airframe}")
    return spec, sp


def run_one(job: tuple) -> dict:
    """One campaign drill in this process → a plain dict (picklable); a crash is a failed row.
    job: (airframe, index, seed, envelope[, through, first instance])."""
    cpu0 = time.process_time()
    try:
        through = job[4] if len(job) > 4 else "process"
        row = _run_mission(job) if through == "mission" else _run_one(job[:4])
        return row | {"through": through, "cpu_s": round(time.process_time() - cpu0, 3)}
    except Exception as e:  # noqa: BLE001  one broken drill must not lose the campaign
        airframe, index = job[0], job[1]
        return {c: "" for c in COLS} | {
            "drill": f"crashed {index:04d}", "airframe": airframe, "kind": "crash",
            "passed": False, "failed_check": "crash", "min_clearance_m": math.nan, "breach": False, "overridden": 0,
            "not_recovered": False,
            "why": f"{type(e).__name__}: {e}", "_events": [], "_track": [],
        }  # fmt: skip


def _run_one(job: tuple) -> dict:
    from skyherd.safety.campaign import drill_rng, kinds_for, make_drill, make_vehicle
    from skyherd.safety.drills import DrillParams, run_drill

    airframe, index, seed, envelope = job
    spec, sp = _load(airframe, envelope)
    p = DrillParams()
    ks = kinds_for(airframe)
    d = make_drill(ks[index % len(ks)], index, drill_rng(seed, airframe, index), spec, p)
    sink = _Collect()
    r = run_drill(d.script, make_vehicle(d, seed), d.spec, sp, p, sink)
    end_mode = ("ai", "fallback", "pid")[int(r.track["mode"][-1])]
    return _row(r, airframe, d.kind, spec, d.spec, sink, end_mode, r.track["pos"][::10])


def _row(r, airframe: str, kind: str, spec, moved, sink: _Collect, end_mode: str, pos) -> dict:
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
        "_track": (pos - np.r_[_offset(moved, spec), 0.0]).tolist(),
    }  # fmt: skip


def _run_mission(job: tuple) -> dict:
    """One campaign drill flown by the companion's mission code (mission.drill_link)."""
    from skyherd.mission.drill_link import run_mission_drill
    from skyherd.safety.campaign import drill_rng, kinds_for, make_drill
    from skyherd.safety.drills import DrillParams

    airframe, index, seed, envelope, _, instance = job
    spec, _ = _load(airframe, envelope)
    ks = kinds_for(airframe)
    kind = ks[index % len(ks)]
    sink = _Collect()
    r = run_mission_drill(kind, airframe, index, seed, instance, sink, envelope)
    moved = make_drill(kind, index, drill_rng(seed, airframe, index), spec, DrillParams()).spec
    track = [row[1:] for row in r.track]
    return _row(r, airframe, kind, spec, moved, sink, r.end_mode, track) | {
        "decisions": r.setpoints,
        "sim_s": round(r.sim_s, 2),
    }


def _offset(moved, base) -> np.ndarray:
    """How far the drill's fence was moved (fixed-wing): tracks are drawn in the base frame."""
    if not moved.inclusions:
        return np.zeros(2)
    return moved.inclusions[0].points[0] - base.inclusions[0].points[0]


def run_campaign(args) -> int:
    from tqdm import tqdm

    airframes = ["quadrotor", "fixedwing"] if args.airframe == "all" else [args.airframe]
    specs = {a: _load(a, args.envelope) for a in airframes}
    n = args.campaign
    through = getattr(args, "through", "process")
    jobs = [(a, i, args.seed, args.envelope, through, getattr(args, "instance", 85))
            for i in range(n) for a in airframes]  # fmt: skip
    run_dir = RunFolder("drill", root=args.runs_dir)
    run_dir.write_config({"args": {k: v for k, v in vars(args).items() if not k.startswith("_")},
                          "seed": args.seed, "campaign": n, "airframes": airframes,
                          "constraint_sets": {a: s.describe() for a, (s, _) in specs.items()},
                          "supervisor": {a: sp for a, (_, sp) in specs.items()}})  # fmt: skip
    events = run_dir.events()
    metrics = run_dir.metrics(COLS)
    rows: list[dict] = []
    tracks: dict[str, list] = {a: [] for a in airframes}

    def keep(row: dict) -> None:
        row.setdefault("_tol", 0.0)
        for e in row.pop("_events"):
            events.write({"drill": row["drill"], "airframe": row["airframe"], **e})
        tracks[row["airframe"]].append((row["kind"], row.pop("_track")))
        metrics.write(row)
        rows.append(row)

    ray_address = getattr(args, "ray_address", None)
    with tqdm(total=len(jobs), desc="campaign", unit="drill") as bar:
        if args.workers == 1 and ray_address is None:
            for job in jobs:
                keep(run_one(job))
                bar.update(1)
        else:  # Ray tasks or a process pool; rows streamed to metrics.csv as drills finish
            from skyherd.runio.parallel import map_unordered

            for _, row in map_unordered(run_one, jobs, getattr(args, "backend", "auto"),
                                        args.workers, ray_address, say=tqdm.write):  # fmt: skip
                keep(row)
                bar.update(1)
    events.close()
    metrics.close()
    table, closest, totals, bad = summarize(rows) if rows else ("", "", "no in-process drills", 0)
    target = getattr(args, "target_bound", TARGET_BOUND)
    proof = bounds(rows, target) if rows else ""
    if not args.no_plots and rows:
        plot(rows, tracks, {a: s for a, (s, _) in specs.items()}, run_dir.file("campaign.png"))
    versions = ", ".join(f"{a}: {s.name} {s.version}" for a, (s, _) in specs.items())
    print(table)
    print(closest)
    print(proof)
    print(totals)
    print(f"flown through: {THROUGH_TEXT[through]}")
    print(f"constraint sets: {versions}")
    print(f"run folder: {run_dir.path}")
    fails = [
        f"- {r['drill']} ({r['airframe']}): {r['why']}" for r in rows if not _flag(r, "passed")
    ]
    run_dir.write_summary(
        f"# skyherd drill --campaign {n} --through {through} (seed {args.seed})\n\n"
        f"{THROUGH_TEXT[through]}\n\nConstraint sets: {versions}\n\n"
        f"{table}\n\n## Closest approaches\n\n{closest}\n\n## What it proves\n\n{proof}\n\n"
        f"{totals}\n"
        + ("\n## Drills that failed a check\n" + "\n".join(fails[:200]) + "\n" if fails else "")
    )
    return 1 if bad else 0


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
    failed = sum(not _flag(r, "passed") for r in rows)
    stuck = _flag_sum(rows, "not_recovered")
    unjudged = sum(r.get("end_mode") in ("fallback", "pid") and not r["yielded"]
                   and not _flag(r, "not_recovered") for r in rows)  # fmt: skip
    own = sum(_own_counts(r) for r in rows)
    crashed = sum(r["kind"] == "crash" for r in rows)  # unjudged: never a pass
    path = sum(_own_path(r) for r in rows)
    first: dict[str, int] = {}
    for r in rows:
        if not _flag(r, "passed"):
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
    from skyherd.safety.campaign import CONFIDENCE, breach_upper_bound, drills_needed

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
    from skyherd.safety.campaign import kinds_for

    try:
        ks = kinds_for(r["airframe"])
        return ks[int(str(r["drill"]).split()[-1]) % len(ks)]
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


def plot(rows, tracks, specs, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from skyherd.scripts.drill import _draw_fence

    afs = sorted(specs)
    fig, axs = plt.subplots(2, len(afs), figsize=(7 * len(afs), 11), squeeze=False)
    for j, a in enumerate(afs):
        rs = [r for r in rows if r["airframe"] == a]
        kinds = sorted({r["kind"] for r in rs})
        ax = axs[0, j]
        for i, k in enumerate(kinds):
            c = np.array([r["min_clearance_m"] for r in rs if r["kind"] == k])
            x = i + np.random.default_rng(i).uniform(-0.25, 0.25, len(c))
            ax.scatter(x, c, s=4, alpha=0.6)
        ax.axhline(0.0, color="r", lw=1)
        ax.set_xticks(range(len(kinds)))
        ax.set_xticklabels(kinds, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("closest approach to the fence [m] (< 0 = breach)")
        ax.set_title(f"{a}: {len(rs)} drills, {sum(r['breach'] for r in rs)} breaches, "
                     f"{sum(r['overridden'] for r in rs)} overridden failsafes")  # fmt: skip
        ax2 = axs[1, j]
        _draw_fence(ax2, specs[a])
        for _k, tr in tracks[a][:400]:
            t = np.asarray(tr)
            if len(t):
                ax2.plot(t[:, 1], t[:, 0], lw=0.3, alpha=0.4)
        ax2.set_aspect("equal")
        ax2.set_xlabel("east [m]")
        ax2.set_ylabel("north [m]")
        ax2.set_title(f"{a}: tracks of the first {min(400, len(tracks[a]))} drills")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
