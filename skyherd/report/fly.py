"""`skyherd fly`'s report, from the run folder the two programs wrote: a table, plots and
summary.md that says how the flight ended (completed / aborted with the reason / interrupted)."""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import sys
from pathlib import Path

import numpy as np

from skyherd.mission.metrics import cross_track, groundair_metrics
from skyherd.report.plots_flight import plot_groundair, plot_orbit
from skyherd.report.reason import flight_reason
from skyherd.runio import atomic_write_text, markdown_table
from skyherd.safety.judge import (
    Check,
    Ending,
    JudgeParams,
    ModeChange,
    Truth,
    failed_text,
    first_failed,
    judge,
)
from skyherd.task.params import TaskParams


def _rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    out = []
    for line in path.read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            pass  # a line cut by a kill: everything before it stands
    return out


def _track(rows: list[dict]) -> np.ndarray:
    return np.array(
        [[float(r["t"]), float(r["north"]), float(r["east"]), float(r["down"])] for r in rows]
    ).reshape(-1, 4)


def _fmt(x, digits: int = 3):
    return (
        "—"
        if x is None or (isinstance(x, float) and not math.isfinite(x))
        else (round(x, digits) if isinstance(x, float) else x)
    )


def _config(run_dir: Path) -> dict:
    """config.json ({} if missing or unreadable)."""
    try:
        cfg = json.loads((run_dir / "config.json").read_text())
    except (OSError, ValueError):
        return {}
    return cfg if isinstance(cfg, dict) else {}


def report(run_dir: Path, args, rc: int, why: str, later: list | None = None) -> bool:
    """Write summary.md (and plots) from the run folder; print the table; True if completed.
    With a list `later` (`skyherd fly`) the ground-air and square plots are appended to it as
    (file name, call) to be made once the verdict is printed (report.ending.make_plots)."""
    comp = {}
    if (run_dir / "companion.json").exists():
        comp = json.loads((run_dir / "companion.json").read_text())
    outcome = comp.get("outcome", "aborted")
    reason = flight_reason(comp.get("reason"), why)
    if rc == 130:
        outcome, reason = "interrupted", "interrupted (Ctrl-C)"
    elif rc != 0 and outcome == "completed":
        outcome = "aborted"
    try:
        checks = judge_run(run_dir, args, comp, outcome, reason)
    except (OSError, ValueError, KeyError, TypeError) as e:  # a run folder the judge cannot read
        checks = [Check("judge", False, "not judged", f"{type(e).__name__}: {e}")]
    failed = first_failed(checks)
    if failed is not None and outcome == "completed":
        outcome, reason = "failed", failed_text(failed)
    ok = outcome == "completed" and rc == 0
    decisions = _jsonl(run_dir / "decisions.jsonl")
    track = _track(_rows(run_dir / "metrics.csv"))
    if getattr(args, "airframe", "") == "fixedwing" or args.mission == "orbit":
        table, title = _orbit_report(run_dir, comp, track)
    elif args.mission == "square":
        table, title = _square_table(decisions, track), f"square mission, {args.side:.0f} m side"
        _plot(later, "track.png", _plot_square, run_dir, track, decisions)
    elif args.mission == "shepherd":
        table, title = _shepherd_report(run_dir, args, comp, decisions, track)
    else:
        world = _rows(run_dir / "world.csv")
        m = groundair_metrics(decisions, world, TaskParams())
        net = comp.get("net", {})
        rows = [
            ["decisions", m["decisions"]],
            ["all UGVs in view [fraction of decisions]", _fmt(m["in_view"])],
            ["footprint / smallest circle [mean]", _fmt(m["footprint_ratio"])],
            ["UGV losses (all-in-view → not)", m["losses"]],
            ["safety-net switches", net.get("switches", "—")],
            ["AI actions projected / held by the net", m["verdicts"]["projected"]],
            ["time in fallback [s]", _fmt(net.get("fallback_s"))],
            ["time under PID [s]", _fmt(net.get("pid_s"))],
            ["autopilot took over", comp.get("yielded") or "no"],
        ]
        table = markdown_table(["metric", "value"], rows)
        team = getattr(args, "ugvs", "as the simulator drives it")
        title = f"ground–air mission, UGV team `{team}`, pilot `{args.pilot}`, {args.duration:.0f} s behind the safety net"
        _plot(later, "groundair.png", plot_groundair, run_dir, decisions, _rows(run_dir / "metrics.csv"),
              world, _config(run_dir).get("envelope"), comp.get("authority") or {})  # fmt: skip
    status = {"completed": "completed", "yielded": "ended: the autopilot took over"}.get(
        outcome, outcome.upper()
    )
    if failed is not None and outcome != "interrupted":
        reason = f"{reason}; first failed check: {failed_text(failed)}"
        if outcome == "failed":
            reason = f"first failed check: {failed_text(failed)}"
    who = f"skyherd {getattr(args, 'command', None) or 'fly'}"  # `skyherd companion` alone too
    lines = [f"# {who}: {status}", "", title + ".", ""]
    signing = _config(run_dir).get("signing")
    if signing:
        lines += [f"MAVLink signing: {signing}.", ""]
    if not ok:
        lines += [f"**Why it ended:** {reason or 'see companion.json and sim.log'}", ""]
    lines += [table]
    verdicts = judge_table(checks)
    lines += ["", "## The judge (safety/judge.py: truth and the companion's records)", "", verdicts]
    if comp.get("configured"):  # --configure-autopilot: what it set, and why
        rows = [[c["name"], f"{c['before']:g}", f"{c['after']:g}", c["reason"].replace("|", "/")]
                for c in comp["configured"]]  # fmt: skip
        lines += ["", "## Autopilot parameters set (--configure-autopilot; nothing restored)", "",
                  markdown_table(["parameter", "before", "after", "why"], rows)]  # fmt: skip
    if any("explanation" in d for d in decisions):  # a modular policy said why it acted
        from skyherd.policy.education.timeline import read_decisions, timeline

        told = timeline(read_decisions(run_dir / "decisions.jsonl")[0])
        lines += [
            "",
            "## Timeline (which skill acted, why, and the net's verdict)",
            "",
            *[f"- {x}" for x in told[:40]],
        ]
    atomic_write_text(run_dir / "summary.md", "\n".join(lines))
    print(table)
    if not ok:
        print(verdicts)
    files = sorted({p.name for p in run_dir.iterdir()} | {name for name, _ in later or ()})
    files = ["report.html"] + [f for f in files if f != "report.html"]  # written with the ending
    print(f"{who}: {status}{'' if ok else ': ' + (reason or '')}; {', '.join(files)} in {run_dir}")
    return ok


def judge_run(run_dir: Path, args, comp: dict, outcome: str, reason: str) -> list[Check]:
    """skyherd.safety.judge on the run folder: world.csv (the truth; without a simulator, the
    autopilot's own track in metrics.csv, said so), the envelope of config.json (a mission
    flown without a net, the square, is judged on the airframe's default fence and ceiling, no
    floor), modes.jsonl, frames.csv and companion.json's hand-over window."""
    from skyherd.safety.config import fly_envelope_path, load_envelope
    from skyherd.safety.envelope import CAMERA_TIMEOUT_S  # not the supervisor: no numba, no QP

    cfg = {}
    if (run_dir / "config.json").exists():
        cfg = json.loads((run_dir / "config.json").read_text())
    env = (cfg.get("envelope") or {}).get("path") or getattr(args, "envelope", None)
    orbit = getattr(args, "mission", "") == "orbit"  # `skyherd companion --mission orbit`
    airframe = "fixedwing" if orbit else getattr(args, "airframe", "quadrotor")
    spec, _ = load_envelope(env or fly_envelope_path(airframe))
    guards = getattr(spec, "guards", None)  # the camera guard's timeout ("off": the default's)
    camera_s = getattr(guards, "camera_timeout_s", None) or CAMERA_TIMEOUT_S
    world = _rows(run_dir / "world.csv")
    rows = world or _rows(run_dir / "metrics.csv")
    truth = Truth.from_rows(rows)
    changes = [ModeChange(float(r["t"]), r.get("mode") or "", bool(r.get("armed")),
                          r.get("by_companion"),
                          math.nan if r.get("alt_m") is None else float(r["alt_m"]))
               for r in _jsonl(run_dir / "modes.jsonl")]  # fmt: skip
    auth = comp.get("authority") or {}
    t0, t1 = auth.get("t_start"), auth.get("t_end")
    window = (float(t0), float(t1)) if t0 is not None and t1 is not None else None
    frames, received, rendered = None, None, 0
    if (run_dir / "frames.csv").exists():
        ok = [r for r in _rows(run_dir / "frames.csv") if r.get("status") == "ok" and r.get("t")]
        frames = [float(r["t"]) for r in ok]
        if window is not None:
            received = sum(int(r.get("n") or 1) for r in ok
                           if window[0] - 1e-9 <= float(r["t"]) <= window[1] + 1e-9)  # fmt: skip
    if window is not None:
        rendered = int(np.sum((truth.t >= window[0] - 1e-9) & (truth.t <= window[1] + 1e-9)))
    ending = Ending(
        outcome, reason, bool(auth.get("land", True)), end_mode=str(auth.get("end_mode") or "")
    )
    net_modes = [(float(e["t"]), str(e["to"])) for e in _jsonl(run_dir / "events.jsonl")
                 if e.get("event") == "switch" and "to" in e]  # fmt: skip
    checks = judge(truth, spec, changes, window, frames, rendered, ending, net_modes,
                   JudgeParams(camera_gap_max_s=camera_s,
                               floor=bool(cfg.get("envelope"))), received)  # fmt: skip
    cut = _records_cut(run_dir)
    if cut:  # a full disk or a read-only folder: what was not recorded cannot be judged
        checks = [Check("records", False, "; ".join(cut), "the judge reads these records: what "
                        "they lost after the cut is not judged, so the flight cannot pass")] + checks  # fmt: skip
    if not world:  # no simulator: say whose track the truth checks used
        checks = [dataclasses.replace(c, figure=c.figure + " (autopilot's track: no simulator truth)")
                  if c.name in ("fence", "armed", "end") else c for c in checks]  # fmt: skip
    return checks


JUDGED_RECORDS = ("world.csv", "metrics.csv", "modes.jsonl", "frames.csv", "events.jsonl")


def _records_cut(run_dir: Path) -> list[str]:
    """The records the judge reads that a full disk or a read-only folder cut (sim_stats.json's
    and companion.json's records_cut), as "file (who): error, N dropped"."""
    out = []
    for name, who in (("sim_stats.json", "sim"), ("companion.json", "companion")):
        try:
            doc = json.loads((run_dir / name).read_text())
        except (OSError, ValueError):
            continue
        cuts = doc.get("records_cut") if isinstance(doc, dict) else None
        for c in cuts or []:
            if isinstance(c, dict) and c.get("file") in JUDGED_RECORDS:
                dropped = c.get("dropped")
                out.append(f"{c['file']} ({who}) cut: {c.get('error')}"
                           + (f", {dropped} records dropped" if dropped is not None else ""))  # fmt: skip
    return out


def judge_table(checks: list[Check]) -> str:
    return markdown_table(["check", "result", "figure", "reason"],
                          [[c.name, "pass" if c.ok else "FAIL", c.figure, c.reason] for c in checks])  # fmt: skip


def _legs(decisions: list[dict]) -> list[tuple[float, float, np.ndarray]]:
    """(t_start, t_end, target) of each square leg, from the proposed targets' changes."""
    legs: list[list] = []
    for d in decisions:
        target = np.array(d["proposed"]["pos_ned"])
        if not legs or np.linalg.norm(target - legs[-1][2]) > 1e-6:
            if legs:
                legs[-1][1] = float(d["t"])
            legs.append([float(d["t"]), math.nan, target])
    if legs:
        legs[-1][1] = float(decisions[-1]["t"])
    return [tuple(x) for x in legs]


def _square_table(decisions: list[dict], track: np.ndarray) -> str:
    rows = []
    start = np.zeros(3)
    for i, (t0, t1, target) in enumerate(_legs(decisions)):
        sel = (
            track[(track[:, 0] >= t0) & (track[:, 0] <= t1)][:, 1:]
            if len(track)
            else np.zeros((0, 3))
        )
        rows.append(
            [
                i + 1,
                f"{target[0]:.0f} N {target[1]:.0f} E",
                round(t1 - t0, 1),
                _fmt(cross_track(sel, start, target)),
            ]
        )
        start = target
    return markdown_table(["leg", "to", "time [s]", "max cross-track [m]"], rows)


def _plot(later: list | None, name: str, plot, *args) -> None:
    """`plot(*args)` now (a record it cannot draw from is said: `_plotting`), or appended to
    `later` as (name, call)."""
    if later is None:
        _plotting(name, plot, *args)
    else:
        later.append((name, lambda: plot(*args)))


def _figure(ncols: int, size):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt, *plt.subplots(1, ncols, figsize=size)


def _plot_square(run_dir: Path, track: np.ndarray, decisions: list[dict]) -> None:
    from skyherd.report.plots_flight import phase_spans, shade_phases

    plt, fig, (ax1, ax2) = _figure(2, (12, 4.8))
    c = np.array([leg[2] for leg in _legs(decisions)]).reshape(-1, 3)
    ax1.plot(np.r_[0, c[:, 1]], np.r_[0, c[:, 0]], "k--", lw=1, label="planned")
    if len(track):
        ax1.plot(track[:, 2], track[:, 1], "b-", lw=1.5, label="flown")
        ax1.plot(track[0, 2], track[0, 1], "o", color="tab:green", ms=6, label="start")
        ax1.plot(track[-1, 2], track[-1, 1], "s", color="k", ms=6, label="end")
        shade_phases([ax2], phase_spans(_rows(run_dir / "metrics.csv")), label_ax=ax2)
        ax2.plot(track[:, 0], -track[:, 3], "b-", label="altitude (autopilot's estimate)")
        ax2.set_xlim(0, max(float(track[-1, 0]), 1.0))
        ax2.legend(fontsize=8, loc="lower center")
    ax1.set(xlabel="east [m]", ylabel="north [m]", title="track (NED, about home)")
    ax1.set_aspect("equal")
    ax1.legend(fontsize=8)
    ax2.set(xlabel="simulation time [s]", ylabel="altitude above home [m]")
    fig.tight_layout()
    fig.savefig(run_dir / "track.png", dpi=110)
    plt.close(fig)


def _plotting(name: str, plot, *a) -> None:
    """A figure of the report; a record it cannot draw from is said, and the report goes on."""
    try:
        plot(*a)
    except (ValueError, KeyError, IndexError, TypeError) as e:
        print(f"skyherd fly: no {name} ({type(e).__name__}: {e})", file=sys.stderr)


def _shepherd_report(run_dir: Path, args, comp: dict, decisions: list[dict], track: np.ndarray):
    """Herding metrics from the simulator's truth (policy.shepherd.metrics) into shepherd.json,
    the flight into shepherd.png; the summary's table and title."""
    from skyherd.policy.shepherd.metrics import flock_track, herding_metrics

    world = _rows(run_dir / "world.csv")
    m = herding_metrics(world)
    flown = [
        d for d in decisions if (d.get("explanation") or {}).get("module") in ("collect", "drive")
    ]
    changed = sum(d.get("verdict") != "accepted" for d in flown)
    m.update({"selector": args.shepherd_selector, "decisions": len(flown),
              "drive_fraction": round(sum(d["explanation"]["module"] == "drive" for d in flown) / max(len(flown), 1), 4),
              "net_changed_fraction": round(changed / max(len(flown), 1), 4),
              "net_switches": (comp.get("net") or {}).get("switches")})  # fmt: skip
    atomic_write_text(run_dir / "shepherd.json", json.dumps(m, indent=1) + "\n")
    rows = [["flock centre in the goal region", "yes" if m["success"] else "no"],
            ["time to goal from the hand-over [s]", _fmt(m["time_to_goal_s"])],
            ["flock spread start → end [m]", f"{_fmt(m.get('spread_start_m'))} → {_fmt(m.get('spread_end_m'))}"],
            ["centre to goal start → end [m]",
             f"{_fmt(m.get('goal_distance_start_m'))} → {_fmt(m.get('goal_distance_end_m'))}"],
            ["shepherd decisions (drive fraction)", f"{m['decisions']} ({_fmt(m['drive_fraction'])})"],
            ["decisions the net changed [fraction]", _fmt(m["net_changed_fraction"])],
            ["safety-net switches", m["net_switches"] if m["net_switches"] is not None else "—"],
            ["autopilot took over", comp.get("yielded") or "no"]]  # fmt: skip
    try:
        plt, fig, axs = _figure(2, (12, 4.8))
        t, uav, flock = flock_track(world)
        if len(t):
            for i in range(flock.shape[1]):
                axs[0].plot(flock[:, i, 1], flock[:, i, 0], lw=0.6, alpha=0.6)
            c = flock.mean(axis=1)
            axs[0].plot(c[:, 1], c[:, 0], "r-", lw=2, label="flock centre")
            axs[0].plot(uav[:, 1], uav[:, 0], "k-", lw=1.2, label="UAV (shepherd)")
            spread = [float(np.linalg.norm(f - f.mean(axis=0), axis=1).mean()) for f in flock]
            axs[1].plot(t, spread, "b-", label="spread [m]")
            axs[1].plot(
                t,
                np.linalg.norm(c - np.asarray(m["goal_ne"]), axis=1),
                "r-",
                label="centre to goal [m]",
            )
        if m.get("goal_ne"):
            g = m["goal_ne"]
            axs[0].add_patch(
                plt.Circle((g[1], g[0]), m["goal_radius_m"], color="g", alpha=0.25, label="goal")
            )
            axs[1].axhline(m["goal_radius_m"], color="g", ls=":", label="goal radius")
        axs[0].set(
            xlabel="east [m]",
            ylabel="north [m]",
            title=f"shepherd ({args.shepherd_selector} selector)",
        )
        axs[0].set_aspect("equal", adjustable="datalim")
        axs[0].legend(fontsize=8)
        axs[1].set(xlabel="time from the hand-over [s]", ylabel="[m]", title="herding")
        axs[1].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(run_dir / "shepherd.png", dpi=100)
        plt.close(fig)
    except (ValueError, KeyError, IndexError) as e:  # the table still goes out
        print(f"skyherd fly: no shepherd.png ({type(e).__name__}: {e})", file=sys.stderr)
    title = (f"shepherd mission, flock of {m.get('agents', '?')} UGVs, {args.shepherd_selector} selector, "
             f"up to {args.duration:.0f} s behind the safety net")  # fmt: skip
    return markdown_table(["metric", "value"], rows), title


def _orbit_report(run_dir: Path, comp: dict, track: np.ndarray) -> tuple[str, str]:
    """The orbit's figures after it was established, judged on the simulator's truth
    (world.csv: the aircraft and every UGV at each camera instant) and on what the companion's
    camera saw (sight.csv); track.png."""
    orbit = comp.get("orbit", {})
    plan = orbit.get("plan", {})
    t_est = orbit.get("t_established")
    world = _rows(run_dir / "world.csv")
    sight = _rows(run_dir / "sight.csv")
    R, h = plan.get("radius_m", float("nan")), plan.get("altitude_m", float("nan"))
    t_end = orbit.get("t_orbit_end") or float("inf")

    def during(r) -> bool:  # the established orbit, before the landing
        return t_est is not None and t_est <= float(r["t"]) <= t_end

    after = [r for r in world if during(r)]
    rad_err, alt_err = [], []
    for r in after:
        n_ugv = sum(1 for k in r if k.endswith("_n") and k.startswith("ugv"))
        c = np.mean([[float(r[f"ugv{i}_n"]), float(r[f"ugv{i}_e"])] for i in range(n_ugv)], axis=0)
        d = float(np.hypot(float(r["north"]) - c[0], float(r["east"]) - c[1]))
        rad_err.append(abs(d - R))
        alt_err.append(abs(-float(r["down"]) - h))
    seen = [r for r in sight if during(r)]
    all_in = float(np.mean([int(r["all_in_view"]) for r in seen])) if seen else float("nan")
    net = comp.get("net", {})
    rows = [
        ["orbit radius R / altitude h [m]", f"{_fmt(R)} / {_fmt(h)}"],
        ["hand-over → established (sim) [s]",
         _fmt(t_est - orbit["t_handover"]) if t_est is not None and orbit.get("t_handover") else "—"],
        ["frames in the established orbit", len(seen)],
        ["all UGVs detected [fraction of those frames]", _fmt(all_in)],
        ["|distance to the team's centre − R|, p95 [m] (truth)",
         _fmt(float(np.percentile(rad_err, 95))) if rad_err else "—"],
        ["|altitude − h|, p95 [m]", _fmt(float(np.percentile(alt_err, 95))) if alt_err else "—"],
        ["orbit centre held back by the fence [decisions]", orbit.get("centre_limited", "—")],
        ["safety-net switches", net.get("switches", "—")],
        ["time in fallback [s]", _fmt(net.get("fallback_s"))],
        ["autopilot took over", comp.get("yielded") or "no"],
    ]  # fmt: skip
    if world:
        _plotting("track.png", plot_orbit, run_dir, world, _rows(run_dir / "metrics.csv"), plan,
                  t_est, _config(run_dir).get("envelope"), comp.get("authority") or {}, sight,
                  _jsonl(run_dir / "decisions.jsonl"))  # fmt: skip
    return markdown_table(["metric", "value"], rows), "fixed-wing orbit over the UGV team"
