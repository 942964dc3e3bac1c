"""Benchmark: how fast K lockstep quadrotor SITL vehicles run with their K MAVLink clients.

For each K the `LockstepSwarm` runs unpaced (speed-up 0: as fast as the machine goes) with
one connected `VehicleClient` per vehicle (real loopback UDP, all telemetry streams at their
default rates, each client receiving and parsing), vehicles idle on the ground. The real-time
factor it reaches is the most `skyherd fly --mission formation --speedup S` can sustain.

    .venv/bin/python bench/bench_formation.py [--quick] [--instance N]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from flight.geo import DEFAULT_HOME  # noqa: E402
from hil.formation import LockstepSwarm, open_clients, vehicle_homes  # noqa: E402
from policy.sql.layout import STARTS  # noqa: E402
from runio.runfolder import markdown_table  # noqa: E402


def measure(k: int, sim_s: float, instance: int) -> list:
    starts = list(STARTS[k]) if k in STARTS else [(1, 1 + 2 * i) for i in range(k)]
    swarm = LockstepSwarm(vehicle_homes(DEFAULT_HOME, starts, 2.0), instance, speedup=0)
    clients, _ = open_clients(swarm.instances, None)
    try:
        swarm.start()
        for c in clients:
            c.wait_ready(timeout=30.0)
        t0, w0, c0 = swarm.t, time.monotonic(), time.process_time()
        while swarm.t - t0 < sim_s and not swarm.error:
            time.sleep(0.05)
        sim, wall, cpu = swarm.t - t0, time.monotonic() - w0, time.process_time() - c0
        pos_ok = all(c.telemetry.pos_ned is not None for c in clients)
    finally:
        for c in clients:
            c.close()
        swarm.close()
    return [k, f"{sim / wall:.1f}x", f"{sim / cpu:.1f}x", f"{1e6 * wall / (sim * 250 * k):.0f}",
            "yes" if pos_ok and not swarm.error else f"NO {swarm.error}"]  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K = 1, 4 and 5 s of simulation")
    ap.add_argument(
        "--instance", type=int, default=170, help="first vehicle instance (default 170)"
    )
    args = ap.parse_args()
    ks, sim_s = ((1, 4), 5.0) if args.quick else ((1, 4, 9, 16), 10.0)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"formation swarm benchmark: {sim_s:g} s simulated per K, unpaced, clients attached")
    print(f"cores {os.cpu_count()}, load average {load:.2f} (a loaded machine slows every row)\n")
    rows = [measure(k, sim_s, args.instance) for k in ks]
    print(markdown_table(["K", "real-time factor (wall)", "real-time factor (CPU)",
                          "wall us per vehicle step (4 ms)", "telemetry reached every client"],
                         rows))  # fmt: skip
    print("the wall factor is the largest --speedup the formation mission can sustain at each K")
    return 0


if __name__ == "__main__":
    sys.exit(main())
