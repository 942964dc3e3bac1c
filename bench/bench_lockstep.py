"""The two-program topology measured: `skyherd fly` (sim + companion as child processes).

1. Determinism matrix: the same seed flown at speed-up 1, 10 and as fast as possible (0), with
   and without two busy `yes` processes; SHA-256 (first 12 hex) of decisions.jsonl, world.csv,
   metrics.csv, events.jsonl — identical rows mean identical flights.
2. Closed-loop real-time factor of the ground-air flight: lockstep as fast as possible vs
   free-running at 10× and 20× (paced; its lag — how late each setpoint acts — p50 / p95).
3. The companion's decision latency (tick start → close, wall time) p50 / p95.
4. `make run`'s job (`skyherd fly --speedup 0`): wall and CPU time.

    .venv/bin/python bench/bench_lockstep.py [--quick]
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from skyherd.runio import markdown_table  # noqa: E402

COMPARED = ("decisions.jsonl", "world.csv", "metrics.csv", "events.jsonl")
SKYHERD = [sys.executable, "-m", "skyherd.scripts.cli"]


def fly(args: list[str], busy: bool = False, check: bool = True) -> tuple[Path, float, float]:
    """One `skyherd fly`; returns (run folder, wall s, CPU s of the children)."""
    root = Path(tempfile.mkdtemp(prefix="skyherd-bench-"))
    hogs = [subprocess.Popen(["yes"], stdout=subprocess.DEVNULL) for _ in range(2 if busy else 0)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.monotonic()
    try:
        subprocess.run([*SKYHERD, "fly", *args, "--runs-dir", str(root)], check=check,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    wall = time.monotonic() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime + after.ru_stime) - (before.ru_utime + before.ru_stime)
    if busy:
        cpu = float("nan")  # the hogs' CPU is counted too
    (run,) = root.iterdir()
    return run, wall, cpu


def digest(run: Path) -> str:
    """First 12 hex digits of each compared file's SHA-256 (a formation: of the K vehicles'
    world.csv together, as one more hash)."""
    h = [
        hashlib.sha256((run / n).read_bytes()).hexdigest()[:12]
        for n in COMPARED
        if (run / n).exists()
    ]
    worlds = sorted(run.glob("uav*/world.csv"))
    if worlds:
        h.append(hashlib.sha256(b"".join(p.read_bytes() for p in worlds)).hexdigest()[:12])
    return " ".join(h)


def sim_stats(run: Path) -> dict:
    p = run / "sim_stats.json"
    return json.loads((p if p.exists() else run / "uav0" / "sim_stats.json").read_text())


def formation_plan() -> str:
    """K = 9 from the study's start cells, 6 cells north in lock-step (a file for --policy-file)."""
    from skyherd.policy.sql.layout import STARTS

    f = Path(tempfile.mkdtemp(prefix="skyherd-bench-")) / "plan_K9.json"
    f.write_text(json.dumps([[[x, y + i] for i in range(7)] for x, y in STARTS[9]]))
    return str(f)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="shorter flights, no 1× runs")
    ap.add_argument("--perf-only", action="store_true", help="skip the determinism matrix")
    a = ap.parse_args()
    dur = "6" if a.quick else "10"
    print(f"load average at start: {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    missions = {
        "groundair": ["--duration", dur, "--instance", "5", "--zenoh-port", "7458"],
        "square": ["--mission", "square", "--side", "10", "--altitude", "5", "--instance", "5",
                   "--zenoh-port", "7458"],
        "formation K=9": ["--mission", "formation", "--agents", "9", "--policy-file",
                          formation_plan(), "--instance", "5"],
        "orbit": ["--airframe", "fixedwing", "--orbit-duration", "10", "--orbit-no-land",
                  "--instance", "5", "--zenoh-port", "7458"],
    }  # fmt: skip
    speedups = ["10", "0"] if a.quick else ["1", "10", "0"]
    if a.perf_only:
        missions, speedups = {"groundair": missions["groundair"]}, ["0"]
    rows, rtf = [], {}
    for name, args in missions.items():
        for s in speedups:
            for busy in (False, True):
                run, wall, _ = fly([*args, "--speedup", s], busy)
                st = sim_stats(run)
                rows.append(
                    [
                        name,
                        s,
                        "yes" if busy else "no",
                        digest(run),
                        round(st["real_time_factor"], 1),
                    ]
                )
                if name == "groundair" and s == "0" and not busy:
                    rtf["lockstep"] = st
                    rtf["companion"] = json.loads((run / "companion.json").read_text())
    print("\n## Determinism matrix (same seed; hashes of " + ", ".join(COMPARED) + ")\n")
    print(
        markdown_table(
            ["mission", "speed-up", "2 busy procs", "run-folder hashes", "sim real-time factor"],
            rows,
        )
    )
    for name in missions:
        hashes = {r[3] for r in rows if r[0] == name}
        print(
            f"{name}: {'identical' if len(hashes) == 1 else 'DIFFERENT'} across {sum(r[0] == name for r in rows)} runs"
        )
    perf = [
        [
            "lockstep, as fast as possible",
            round(rtf["lockstep"]["real_time_factor"], 1),
            "— (L = 0.02 s exactly)",
            rtf["companion"]["outcome"],
        ]
    ]
    for s in ("10", "20"):
        run, _, _ = fly([*missions["groundair"], "--speedup", s, "--free-run"], check=False)
        st = json.loads((run / "sim_stats.json").read_text())
        out = json.loads((run / "companion.json").read_text())
        lag = st["free_run_lag"]
        ended = out["outcome"] + (
            f" ({out['reason'][:60]}…)" if out["outcome"] != "completed" else ""
        )
        perf.append([f"free-running, paced {s}×", round(st["real_time_factor"], 1),
                     f"{lag.get('p50_s', float('nan')):.3f} / {lag.get('p95_s', float('nan')):.3f} s", ended])  # fmt: skip
    print("\n## Closed-loop real-time factor, ground-air\n")
    print(
        markdown_table(
            ["mode", "sim real-time factor", "setpoint lag p50 / p95 [sim s]", "flight"], perf
        )
    )
    c = rtf["companion"]
    print(f"\ncompanion decision latency (wall): p50 {1e3 * c['decide_wall_p50_s']:.1f} ms, "
          f"p95 {1e3 * c['decide_wall_p95_s']:.1f} ms over {c['ticks']} ticks")  # fmt: skip
    run, wall, cpu = fly(["--speedup", "0", "--instance", "5", "--zenoh-port", "7458"])
    print(f"\n`make run`'s job (skyherd fly --speedup 0: 60 s behind the net): wall {wall:.1f} s, "
          f"CPU {cpu:.1f} s (sim + companion + fly)")  # fmt: skip


if __name__ == "__main__":
    main()
