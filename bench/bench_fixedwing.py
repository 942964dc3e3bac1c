"""Real-time factor of the fixed-wing: JSBSim alone, and JSBSim with the autopilot flying.

Prints a table: simulated seconds, wall and CPU seconds, real-time factors (goal ≥ 150× with
the autopilot), and flight figures (loiter radius and altitude errors, touchdown point).
The CPU-time factor is the one to compare across machines and loads: the wall-clock one
drops when other processes share the cores. `--quick` for a short run.
Run: .venv/bin/python bench/bench_fixedwing.py [--quick]
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from skyherd.flight.autopilot_api import FlightMode, MissionCommand, MissionItem  # noqa: E402
from skyherd.flight.fixedwing.attitude import InnerGains  # noqa: E402
from skyherd.flight.fixedwing.autopilot import FixedWingAutopilot, Phase  # noqa: E402
from skyherd.flight.fixedwing.jsbsim_model import JSBSimPlane, ModelParams  # noqa: E402
from skyherd.flight.fixedwing.tecs import TecsGains  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402

GOAL = 150.0


class Timer:
    """Wall and CPU (this process) seconds of a `with` block."""

    def __enter__(self) -> Timer:
        self.w0, self.c0 = time.perf_counter(), time.process_time()
        return self

    def __exit__(self, *exc: object) -> None:
        self.wall = time.perf_counter() - self.w0
        self.cpu = time.process_time() - self.c0


def bench_jsbsim(sim_s: float) -> tuple[float, Timer]:
    """JSBSim only, trimmed controls held, 50 Hz `step` calls (3 physics steps each)."""
    p = JSBSimPlane()
    trim = p.reset_airborne(100.0, 24.0)
    n = round(sim_s / 0.02)
    with Timer() as tm:
        for _ in range(n):
            p.step(0.02, trim)
    return n * 0.02, tm


def bench_loiter(sim_s: float) -> tuple[float, Timer, float, float]:
    """Autopilot in HOLD (loiter). Returns sim s, wall s, max radius error %, max alt error m."""
    ap = FixedWingAutopilot()
    ap.start_in_air(60.0, 24.0)
    ap.set_mode(FlightMode.HOLD)
    n = round(sim_s / ap.control_dt)
    settle = round(40.0 / ap.control_dt)
    c, r = ap.loiter_center, ap.loiter_radius
    rad_err, alt_err = 0.0, 0.0
    with Timer() as tm:
        for i in range(n):
            ap.step()
            s = ap.state
            alt_err = max(alt_err, abs(s.altitude - 60.0))
            if i >= settle:
                rad_err = max(rad_err, abs(math.hypot(*(s.pos_ned[:2] - c)) - r) / r)
    return n * ap.control_dt, tm, 100.0 * rad_err, alt_err


def bench_mission() -> tuple[float, Timer, str]:
    """Runway take-off, four waypoints, RTL, landing on home's runway, disarm."""
    ap = FixedWingAutopilot(params={"RTL_LAND_DELAY": 0.0})
    wps = [(500, 0, -50), (500, 500, -60), (0, 500, -60), (-200, 250, -50)]
    items = [MissionItem(MissionCommand.TAKEOFF, np.array([0.0, 0.0, -40.0]))]
    items += [MissionItem(MissionCommand.WAYPOINT, np.array(p, dtype=float)) for p in wps]
    items += [MissionItem(MissionCommand.RETURN_TO_LAUNCH, np.zeros(3))]
    ap.set_mission(items)
    ap.arm()
    ap.set_mode(FlightMode.MISSION)
    td = None
    with Timer() as tm:
        for _ in range(round(900.0 / ap.control_dt)):
            ap.step()
            s = ap.state
            if td is None and ap.phase == Phase.ROLLOUT:
                td = s.pos_ned.copy()
            if not ap.armed:
                break
    out = "landed" if not ap.armed and s.on_ground else f"not landed ({ap.phase.value})"
    if td is not None:
        out += f", touchdown {td[0]:.0f} m N {td[1]:.1f} m E of home"
    return ap.clock.t, tm, out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="short runs (a few seconds in all)")
    args = ap.parse_args(argv)
    sim = 120.0 if args.quick else 600.0
    print(f"{ModelParams()}\n{InnerGains()}\n{TecsGains()}\n")

    rows = []
    worst: list[float] = []

    def row(name: str, sim_s: float, tm: Timer, figures: str, counts: bool) -> None:
        rows.append([name, sim_s, tm.wall, tm.cpu, sim_s / tm.wall, sim_s / tm.cpu, figures])
        if counts:
            worst.append(sim_s / tm.cpu)

    s, tm = bench_jsbsim(sim)
    row("JSBSim J3Cub alone (150 Hz)", s, tm, "", False)
    s, tm, rerr, aerr = bench_loiter(sim)
    row("autopilot HOLD (loiter)", s, tm, f"radius err {rerr:.2f} %, alt err {aerr:.2f} m", True)
    s, tm, note = bench_mission()
    row("take-off, mission, RTL, land", s, tm, note, True)
    head = ["run", "sim s", "wall s", "cpu s", "RTF wall ×", "RTF cpu ×", "figures"]
    print(markdown_table(head, rows))
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    w = min(worst)
    print(f"real-time factor with the autopilot (CPU time): {w:.0f}× (goal ≥ {GOAL:.0f}×): "
          f"{'met' if w >= GOAL else 'NOT met'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
