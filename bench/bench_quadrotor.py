"""Real-time factor of the quadrotor with its autopilot at 1 kHz physics.

    .venv/bin/python bench/bench_quadrotor.py [--quick] [--control-dt 0.004] [--fence]

Prints a table: the physics kernel alone, the `Quadrotor.step` wrapper, and the full
`MultirotorAutopilot.step` (commander + navigator + compiled cascade + physics) flying a
scripted flight (takeoff, a 40 m square in offboard, RTL and landing). Goal: >= 200x.
Then the cost of a step with the vehicle's fence on and with a fault plan (gusts, noise, a
GPS glitch) against the plain step, in the same run. `--fence` adds the table of how far the
vehicle's own fence reaction (GF_ACTION 2) ends beyond a 160 m fence, by speed and tailwind.
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

from types import SimpleNamespace  # noqa: E402

from skyherd.flight.airframes_registry import PX4_STANDIN  # noqa: E402
from skyherd.flight.autopilot_api import FlightMode, Setpoint  # noqa: E402
from skyherd.flight.faults import parse_fault_args  # noqa: E402
from skyherd.flight.multirotor import MultirotorAutopilot  # noqa: E402
from skyherd.flight.quadrotor import Quadrotor, QuadrotorParams, WindModel  # noqa: E402
from skyherd.flight.quadrotor_kernels import physics_steps  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402


def bench_kernel(n: int) -> float:
    """Seconds of wall time per physics step, compiled kernel alone."""
    q = Quadrotor(QuadrotorParams.from_toml())
    q.reset(pos_ned=(0, 0, -1e5))  # far up: it falls for the whole run
    u = np.full(4, 0.5)
    physics_steps(q.x, q.aux, q.p, u, 0.001, 10)  # warm-up
    t0 = time.perf_counter()
    physics_steps(q.x, q.aux, q.p, u, 0.001, n)
    return (time.perf_counter() - t0) / n


def bench_wrapper(n_calls: int, dt: float) -> float:
    """Seconds of wall time per `Quadrotor.step(dt)` call."""
    q = Quadrotor(QuadrotorParams.from_toml())
    q.reset(pos_ned=(0, 0, -1e5))
    cmd = np.full(4, 0.5)
    q.step(dt, cmd)
    t0 = time.perf_counter()
    for _ in range(n_calls):
        q.step(dt, cmd)
    return (time.perf_counter() - t0) / n_calls


def scripted_flight(ap: MultirotorAutopilot, sim_s: float) -> dict[str, float]:
    """Cycles of: takeoff to 20 m, a 40 m square in offboard (setpoints at 50 Hz), RTL and
    landing, until sim_s of simulation time. Wall and CPU time of the whole loop."""
    corners = [(40.0, 0.0), (40.0, 40.0), (0.0, 40.0), (0.0, 0.0)]
    n = round(sim_s / ap.control_dt)
    every = max(1, round(0.02 / ap.control_dt))
    leg = round(10.0 / ap.control_dt)
    climb = round(12.0 / ap.control_dt)
    step = ap.step
    t0, c0 = time.perf_counter(), time.process_time()
    k = 0
    while k < n:
        ap.arm()
        ap.takeoff(20.0)
        m = min(climb, n - k)
        for _ in range(m):
            step()
        k += m
        for c in corners:
            sp = Setpoint(pos_ned=np.array([c[0], c[1], -20.0]))
            ap.set_offboard_setpoint(sp)
            ap.set_mode(FlightMode.OFFBOARD)
            m = min(leg, n - k)
            for j in range(m):
                if j % every == 0:
                    ap.set_offboard_setpoint(sp)
                step()
            k += m
        ap.return_to_launch()
        while k < n and ap.armed:
            step()
            k += 1
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    return {"wall": wall, "cpu": cpu, "steps": k, "sim_s": k * ap.control_dt}


def _fly(ap: MultirotorAutopilot, seconds: float, target: np.ndarray | None = None) -> np.ndarray:
    """Step for `seconds` (streaming an offboard position target if given); (n, 4) t, pos."""
    n = round(seconds / ap.control_dt)
    out = np.empty((n, 4))
    for k in range(n):
        if target is not None:
            ap.set_offboard_setpoint(Setpoint(pos_ned=target))
        ap.step()
        s = ap.state
        out[k, 0], out[k, 1:] = s.t, s.pos_ned
    return out


def _settle(t: np.ndarray, y: np.ndarray, target: float, band: float) -> float:
    out = np.nonzero(np.abs(y - target) > band)[0]
    return float(t[out[-1] + 1] - t[0]) if len(out) else 0.0


def step_responses(control_dt: float, params_file=None) -> list[list[str]]:
    """Measured responses (the same flights the tests check); params_file: overrides."""
    rows = []
    ap = MultirotorAutopilot(control_dt=control_dt, params_file=params_file)
    ap.arm()
    ap.takeoff(10.0)
    r = _fly(ap, 15.0)
    alt = -r[:, 3]
    rows.append(
        [
            "takeoff climb 0 -> 10 m",
            f"{_settle(r[:, 0], alt, 10, 0.5):.2f} s",
            f"{100 * max(0.0, alt.max() - 10) / 10:.1f} %",
            "-",
        ]
    )
    for name, tgt, axis, size in (
        ("climb step 10 -> 20 m (offboard)", np.array([0.0, 0.0, -20.0]), 3, -10.0),
        ("north step 0 -> 20 m (offboard)", np.array([20.0, 0.0, -20.0]), 1, 20.0),
    ):
        ap.set_offboard_setpoint(Setpoint(pos_ned=tgt))
        ap.set_mode(FlightMode.OFFBOARD)
        r = _fly(ap, 15.0, tgt)
        y = r[:, axis]
        e = (y - tgt[axis - 1]) * np.sign(size)
        sig = np.sign(e[np.abs(e) > 0.05])
        rows.append(
            [
                name,
                f"{_settle(r[:, 0], y, tgt[axis - 1], 0.05 * abs(size)):.2f} s",
                f"{100 * max(0.0, e.max()) / abs(size):.1f} %",
                f"{int(np.sum(sig[1:] != sig[:-1]))}",
            ]
        )
    ap.set_mode(FlightMode.HOLD)
    _fly(ap, 5.0)
    ref = ap.state.pos_ned.copy()
    r = _fly(ap, 60.0)
    dev = np.linalg.norm(r[:, 1:] - ref, axis=1).max()
    rows.append(["hover 60 s: largest deviation", f"{dev * 100:.1f} cm", "-", "-"])
    windy = MultirotorAutopilot(
        control_dt=control_dt, wind=WindModel((5.0, -3.0, 0.0), gust_std=1.0, gust_tau=2.0, seed=1)
    )
    windy.arm()
    windy.takeoff(10.0)
    _fly(windy, 15.0)
    r = _fly(windy, 60.0)
    dev = np.linalg.norm(r[:, 1:] - [0.0, 0.0, -10.0], axis=1).max()
    rows.append(["hover 60 s, wind 5.8 m/s + 1 m/s gusts", f"{dev * 100:.1f} cm", "-", "-"])
    ap.reposition(np.array([40.0, -30.0, -12.0]))
    _fly(ap, 20.0)
    ap.return_to_launch()
    r = _fly(ap, 80.0)
    rows.append(
        [
            "RTL from (40, -30) m: landing error",
            f"{np.hypot(*r[-1, 1:3]) * 100:.1f} cm",
            "-",
            f"armed={ap.armed}",
        ]
    )
    return rows


def _hovering(**kw) -> MultirotorAutopilot:
    ap = MultirotorAutopilot(**kw)
    ap.arm()
    ap.takeoff(20.0)
    for _ in range(round(12.0 / ap.control_dt)):
        ap.step()
    return ap


def _fence(r: float = 160.0):
    return [SimpleNamespace(kind="circle", inclusion=True, center_ne=np.zeros(2), radius=r)]


def feature_costs(n: int) -> list[list[str]]:
    """CPU µs per hover step: plain, fence on, fault plan on (best of 5 × n), with ratios."""
    plan = parse_fault_args("8,90", "1", "0.3,0.05", ["gps_glitch@15:3,0,0:600"])
    cases = [("plain", {}, False), ("fence (a 160 m circle) on", {}, True)]
    cases.append(("fault plan on (gusts, noise, glitch)", {"faults": plan}, False))
    rows, base = [], None
    for name, kw, fence in cases:
        ap = _hovering(**kw)
        if fence:
            ap.set_fence(_fence())
        best = math.inf
        for _ in range(5):
            c0 = time.process_time()
            for _ in range(n):
                ap.step()
            best = min(best, (time.process_time() - c0) / n)
        base = best if base is None else base
        rows.append([name, f"{best * 1e6:.2f}", f"{best / base:.2f}"])
    return rows


def fence_overshoot() -> list[list[str]]:
    """Offboard velocity straight out of a 160 m circle fence with the wind behind."""
    rows = []
    for wind in (0.0, 8.0, 14.0, 16.0):
        for v in (5.0, 12.0):
            ap = _hovering(wind=WindModel(mean_ned=(wind, 0.0, 0.0)))
            ap.set_fence(_fence())
            sp = Setpoint(vel_ned=np.array([v, 0.0, 0.0]))
            ap.set_offboard_setpoint(sp)
            ap.set_mode(FlightMode.OFFBOARD)
            far, v_breach = -math.inf, math.nan
            for k in range(round(60.0 / ap.control_dt)):
                if ap.mode == FlightMode.OFFBOARD and k % 5 == 0:
                    ap.set_offboard_setpoint(sp)
                if math.isnan(v_breach) and ap.mode == FlightMode.HOLD:
                    v_breach = float(ap.state.vel_ned[0])
                ap.step()
                far = max(far, float(ap.state.pos_ned[0]))
            rows.append(
                [f"{wind:g} m/s", f"{v:g} m/s", f"{v_breach:.1f} m/s", f"{far - 160.0:.1f} m",
                 ap.mode.value]
            )  # fmt: skip
    return rows


def main(argv: list[str] | None = None) -> int:
    ap_ = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap_.add_argument("--quick", action="store_true", help="short run (a few seconds)")
    ap_.add_argument("--control-dt", type=float, default=0.004, help="autopilot period [s]")
    ap_.add_argument("--fence", action="store_true", help="also the fence-overshoot table")
    args = ap_.parse_args(argv)
    sim_s = 120.0 if args.quick else 600.0  # within one battery
    n_kernel = 1_000_000 if args.quick else 10_000_000

    t_warm = time.perf_counter()
    ap = MultirotorAutopilot(control_dt=args.control_dt)
    ap.step()
    warm = time.perf_counter() - t_warm

    k = bench_kernel(n_kernel)
    w = bench_wrapper(20_000 if args.quick else 100_000, args.control_dt)
    ap = MultirotorAutopilot(control_dt=args.control_dt)
    r = scripted_flight(ap, sim_s)
    sim_s = r["sim_s"]
    per_step = r["wall"] / r["steps"]
    rtf = sim_s / r["wall"]
    n_sub = round(args.control_dt / ap.vehicle.physics_dt)
    rows = [
        ["physics kernel alone (1 ms step)", f"{k * 1e6:.3f}", f"{0.001 / k:,.0f}x"],
        [
            f"Quadrotor.step({args.control_dt * 1e3:g} ms), {n_sub} substeps",
            f"{w * 1e6:.2f}",
            f"{args.control_dt / w:,.0f}x",
        ],
        [
            f"MultirotorAutopilot.step ({1 / args.control_dt:g} Hz, {n_sub}x1 ms physics)",
            f"{per_step * 1e6:.2f}",
            f"{rtf:,.0f}x",
        ],
    ]
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"cores {os.cpu_count()}, load average {load:.2f} (a loaded machine slows every row)")
    print(f"first autopilot step incl. compile/cache load: {warm:.2f} s")
    print(
        f"scripted flight: {sim_s:g} s sim in {r['wall']:.2f} s wall, battery left "
        f"{ap.battery_remaining:.3f}, mode {ap.mode.value}"
    )
    print(markdown_table(["what", "wall us per call", "real-time factor"], rows))
    print()
    print(
        markdown_table(
            ["step response", "settling (5 %) / figure", "overshoot", "zero crossings (±5 cm)"],
            step_responses(args.control_dt),
        )
    )
    print()
    print(f"PX4 stand-in ({PX4_STANDIN.relative_to(PX4_STANDIN.parents[2])}):")
    print(
        markdown_table(
            ["step response", "settling (5 %) / figure", "overshoot", "zero crossings (±5 cm)"],
            step_responses(args.control_dt, PX4_STANDIN),
        )
    )
    per_phys = per_step / n_sub
    print(
        f"autopilot + physics: {per_phys * 1e6:.2f} us per 1 ms physics step; "
        f"real-time factor {rtf:,.0f}x wall, {sim_s / r['cpu']:,.0f}x per CPU second "
        f"(goal >= 200x: {'met' if rtf >= 200 else 'NOT met'})"
    )
    print()
    costs = feature_costs(2000 if args.quick else 5000)
    print(markdown_table(["hover step", "CPU us per step", "x plain"], costs))
    if args.fence:
        print()
        head = ["tailwind", "commanded", "speed at breach", "farthest beyond fence", "mode"]
        print(markdown_table(head, fence_overshoot()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
