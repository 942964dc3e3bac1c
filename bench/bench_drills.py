"""Cost of one campaign drill, by airframe: flown by the companion's mission code over loopback
MAVLink in lockstep (`skyherd drill --campaign N`, default `--through mission`:
mission.drill_link) against the in-process drill loop (`--through process`: safety.drills),
as the baseline measured in the same run.

    unshare -n bash -c 'ip link set lo up; PYTHONPATH=$PWD .venv/bin/python bench/bench_drills.py [--drills N]'

The same drills (seed, indices 0..N-1, the kinds in turn) fly both ways, alternated A/B drill
by drill, in this one process (one warm-up drill of each way first, not counted). Figures are
CPU time (time.process_time: every thread of the process — the vehicle's and the
companion's), so another job on the machine changes the wall time, not them. Prints, per
airframe: CPU s per drill (mean, p50, p95) each way, the ratio mission / process, simulation
seconds flown per CPU second, and the projected CPU hours for 1,000 drills per airframe.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skyherd.mission.campaign import run_one
from skyherd.runio.runfolder import markdown_table
from skyherd.safety.campaign_run import DrillJob


def cpu_of(job: DrillJob) -> tuple[float, dict]:
    c0 = time.process_time()
    row = run_one(job)
    return time.process_time() - c0, row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--drills", type=int, default=16, help="drills per airframe (default 16)")
    ap.add_argument("--seed", type=int, default=11, help="campaign seed (default 11)")
    ap.add_argument("--instance", type=int, default=60, help="first vehicle instance (default 60)")
    args = ap.parse_args()
    out = []
    for airframe in ("quadrotor", "fixedwing"):
        for way in ("mission", "process"):  # warm-up: imports, compiled kernels, sockets
            cpu_of(DrillJob(airframe, 10_000, args.seed, None, way, args.instance))
        cpu = {"mission": [], "process": []}
        sim = []
        bad = 0
        for i in range(args.drills):
            order = ("mission", "process") if i % 2 == 0 else ("process", "mission")
            for way in order:
                c, row = cpu_of(DrillJob(airframe, i, args.seed, None, way, args.instance))
                cpu[way].append(c)
                bad += not row["passed"]
                if way == "mission":
                    sim.append(float(row["sim_s"]))
        m, p = np.array(cpu["mission"]), np.array(cpu["process"])
        out.append([airframe, args.drills, f"{m.mean():.3f}", f"{np.percentile(m, 50):.3f}",
                    f"{np.percentile(m, 95):.3f}", f"{p.mean():.3f}", f"{m.mean() / p.mean():.2f}",
                    f"{sum(sim) / m.sum():.0f}", f"{1000 * m.mean() / 3600:.3f}", bad])  # fmt: skip
    print(markdown_table(["airframe", "drills", "mission CPU s/drill (mean)", "p50", "p95",
                          "process CPU s/drill (mean)", "ratio mission / process",
                          "sim s per CPU s (mission)", "CPU h for 1,000 (mission)",
                          "drills failing a check"], out))  # fmt: skip


if __name__ == "__main__":
    main()
