"""Benchmark: the formation as K simulator processes and one companion in lockstep.

For each K, `skyherd fly --mission formation --speedup 0` (as fast as the machine goes), with one
simulator process per vehicle and with two (one per core, a fleet of K/2 each), flies a
short hand-made plan (every vehicle 10 cells north in lock-step, from the study's start cells):
take-off, hand-over, plan, settle, landing. Printed per K: the sustained real-time factor
(simulated time / wall time of the slowest vehicle), the CPU seconds all K+1 programs spent per
simulated second, the companion's decision time per tick (wall, p50 / p95), and whether every
vehicle landed on its target. Baseline, in the same run: one vehicle alone (`world.sim.World`
free-running unpaced, no companion, on the ground), the cost of the physics and the endpoint
without lockstep or a mission — the ratio says what the topology costs per vehicle. First, where
one hovering vehicle's CPU goes: the autopilot and physics alone, then the endpoint, then its
streams (the ones a formation companion reads, then every default stream on both links, with
nobody at the ground stations' port 14550 and with a listener there).

    .venv/bin/python bench/bench_formation.py [--quick] [--instance N]
    .venv/bin/python bench/bench_formation.py --ab-signing ROUNDS   # signed vs --no-signing, K = 16
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from skyherd.policy.sql.layout import STARTS  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402
from skyherd.scripts.cli import main as skyherd  # noqa: E402


def alone(instance: int, sim_s: float = 20.0) -> float:
    """Real-time factor per CPU second of one vehicle with nobody attached (the baseline)."""
    from skyherd.world.sim import World, WorldParams

    w = World(WorldParams(scenario="none", lockstep=False, speedup=0, instance=instance))
    try:
        w.run(1.0)  # the numba kernels load (or compile, on a cold cache) outside the timing
        c0 = time.process_time()
        w.run(sim_s)
        return sim_s / (time.process_time() - c0)
    finally:
        w.close()


def vehicle_costs(instance: int, sim_s: float = 20.0) -> list[tuple[str, float]]:
    """CPU s per simulated s of one hovering vehicle, free-running unpaced, built up from the
    autopilot alone (its 250 Hz loop and the 1 kHz physics) to the endpoint with every stream
    on both links: where a formation simulator's CPU goes before lockstep and a run folder."""
    from pymavlink.dialects.v20 import ardupilotmega as M

    from skyherd.flight.mavlink.streams import DEFAULT_RATES_HZ
    from skyherd.mission.steps import UNREAD_STREAMS
    from skyherd.world.sim import World, WorldParams

    unread = {getattr(M, f"MAVLINK_MSG_ID_{n}") for n in UNREAD_STREAMS}
    w = World(WorldParams(scenario="none", lockstep=False, speedup=0, instance=instance))
    ap, ep = w.autopilot, w.endpoint
    try:
        assert ap.arm().ok and ap.takeoff(10.0).ok
        w.run(15.0)  # climbed, holding 10 m

        def cost(step) -> float:
            c0 = time.process_time()
            n = round(sim_s / ap.control_dt)
            for _ in range(n):
                step()
            return (time.process_time() - c0) / sim_s

        def streams(api: set[int] | None, gcs: bool) -> None:
            for m in DEFAULT_RATES_HZ:
                ep.streams["api"].set_interval(m, 0 if api is None or m in api else -1)
                ep.streams["gcs"].set_interval(m, 0 if gcs else -1)

        def both() -> None:
            ap.step()
            ep.update()

        rows = [("autopilot + physics (hover)", cost(ap.step))]
        streams(set(), False)
        rows.append(("+ endpoint, no streams", cost(both)))
        streams(set(DEFAULT_RATES_HZ) - unread, False)
        rows.append(("+ the streams a formation companion reads (API link)", cost(both)))
        streams(None, True)
        rows.append(("+ every default stream on both links, nobody at 14550 (its heartbeat only)",
                     cost(both)))  # fmt: skip
        gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # a ground station that listens
        try:
            gcs.bind(ep.gcs.remote)
        except OSError:  # a real one is there already: it listens too
            pass
        try:
            rows.append(("+ every default stream on both links, a listener at 14550", cost(both)))
        finally:
            gcs.close()
        return rows
    finally:
        w.close()


def fly(k: int, sims: int, instance: int, root: Path, *extra: str, tag: str = "") -> list:
    plan = [[[x, y + i] for i in range(11)] for x, y in STARTS.get(k, ((1, 1),))]
    f = root / f"plan_K{k}.json"
    f.write_text(json.dumps(plan))
    runs = root / f"K{k}-sims{sims}{tag}"
    w0 = time.monotonic()
    code = skyherd(["fly", "--mission", "formation", "--agents", str(k), "--policy-file", str(f),
                    "--speedup", "0", "--instance", str(instance), "--timeout", "1800",
                    "--sims", str(sims), "--runs-dir", str(runs), *extra])  # fmt: skip
    wall = time.monotonic() - w0
    (run,) = runs.iterdir()
    stats = [json.loads((run / f"uav{i}" / "sim_stats.json").read_text()) for i in range(k)]
    comp = json.loads((run / "companion.json").read_text())
    # each simulator's flight: up to the last tick the companion closed (world.sim._stats)
    sim = min(s["flight_sim_s"] for s in stats)
    sim_wall = max(s["flight_wall_s"] for s in stats)
    # CPU s per simulated s of the simulator processes (a process of n vehicles: each vehicle's
    # stats carry the process's CPU, so each counts 1/n of it)
    c_sims = sum(s["flight_cpu_s"] / s.get("process_vehicles", 1) for s in stats) / sim
    c_comp = comp["cpu_flight_s"] / sim  # ... the companion, from its first tick on
    # lockstep alternates: each tick the companion decides, then the simulators step in
    # parallel; on 2 idle cores one simulated second takes about c_comp + c_sims / 2
    projected = 1.0 / (c_comp + c_sims / min(2.0, sims))
    return [k, sims, f"{sim / sim_wall:.2f}x", f"{c_sims / k:.4f}", f"{c_comp:.4f}", f"{projected:.1f}x",
            f"{1e3 * comp['decide_wall_p50_s']:.1f} / {1e3 * comp['decide_wall_p95_s']:.1f}",
            f"{wall:.0f}", "yes" if code == 0 else f"NO ({comp.get('reason', '')[:60]})"]  # fmt: skip


def ab_signing(k: int, rounds: int, instance: int) -> None:
    """The cost of signing the formation's links: the same flight signed (the default, a
    per-run key) and `--no-signing`, alternated A/B in this run, `rounds` each; CPU s per
    simulated s of the simulators (per vehicle) and of the companion, medians, and the ratios."""
    import statistics

    got: dict[str, list[list]] = {"signed": [], "unsigned": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for name, extra in (("signed", ()), ("unsigned", ("--no-signing",))):
                got[name].append(fly(k, 2, instance, Path(tmp), *extra, tag=f"-{name}{r}"))
    med = {n: [statistics.median(float(row[i]) for row in rows) for i in (3, 4)]
           for n, rows in got.items()}  # fmt: skip
    rows = [[n, f"{m[0]:.4f}", f"{m[1]:.4f}", ", ".join(row[2] for row in got[n]),
             ", ".join(row[-1] for row in got[n])] for n, m in med.items()]  # fmt: skip
    print(markdown_table([f"formation K = {k}, 2 simulator processes",
                          "CPU s per sim s per vehicle (median)", "companion CPU s per sim s (median)",
                          "real-time factors (this machine now)", "all landed"], rows))  # fmt: skip
    s, u = med["signed"], med["unsigned"]
    print(f"\nsigned / unsigned: simulators {s[0] / u[0]:.3f}, companion {s[1] / u[1]:.3f} "
          f"({rounds} alternated rounds each)")  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="K = 1 and 4 only")
    ap.add_argument(
        "--instance", type=int, default=150, help="first vehicle instance (default 150)"
    )
    ap.add_argument("--ab-signing", type=int, default=0, metavar="ROUNDS",
                    help="only the cost of signing: K = 16 signed and --no-signing, alternated")  # fmt: skip
    args = ap.parse_args()
    if args.ab_signing:
        ab_signing(16, args.ab_signing, args.instance)
        return 0
    ks = (1, 4) if args.quick else (1, 4, 9, 16)
    load = os.getloadavg()[0]
    print(f"formation benchmark: K simulators + 1 companion in lockstep, speed-up 0 (unpaced); "
          f"cores {os.cpu_count()}, load average {load:.2f}\n")  # fmt: skip
    base = alone(args.instance)
    print(f"baseline: one vehicle alone, no companion, unpaced: {base:.0f}x real time per CPU "
          f"second ({1 / base:.4f} CPU s per simulated s)\n")  # fmt: skip
    costs = vehicle_costs(args.instance)
    print("where one vehicle's CPU goes (hovering, free-running, no run folder):\n")
    print(markdown_table(["", "CPU ms per simulated s", "x real time per CPU s"],
                         [[n, f"{1e3 * c:.2f}", f"{1 / c:.0f}x"] for n, c in costs]))  # fmt: skip
    print()
    layouts = [(k, g) for k in ks for g in sorted({k, min(k, 2)}, reverse=True)]
    with tempfile.TemporaryDirectory() as tmp:
        rows = [fly(k, g, args.instance, Path(tmp)) for k, g in layouts]
    for r in rows:
        r.insert(4, f"{float(r[3]) * base:.2f}x")
    print(markdown_table(["K", "simulator processes", "real-time factor (sim / wall), this machine now",
                          "CPU s per sim s per vehicle", "per vehicle vs alone",
                          "CPU s per sim s, companion", "projected on 2 idle cores",
                          "decision p50 / p95 [ms wall]", "wall [s]", "all landed"], rows))  # fmt: skip
    print(
        "\nsimulator processes: K = one per vehicle (the layout before fleets), 2 = `fly`'s "
        "default here (one per core, each stepping its vehicles in turn); the flight is the "
        "same in both (tests/e2e/test_formation_flight.py)\n"
        "projected = 1 / (companion + simulators / min(2, processes)) CPU s per simulated s: "
        "what the same flight would sustain on 2 idle cores (CPU time does not depend on the load)"
    )
    print(
        "goal: K = 16 at >= 20x on 2 cores: 2 cores / 20x = 0.100 CPU s per simulated s for "
        "all 17 programs, 6.3 ms per vehicle (simulator and its share of the companion)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
