"""Safety-net timings: monitor check, projection QP (exact, against OSQP and cvxpy), recovery
target, supervisor overhead in the SITL loop.

    .venv/bin/python bench/bench_safety.py [--quick]

Prints p50 / p95 per call (each call timed on its own with perf_counter_ns, so the figures
include ~0.1 µs of timer overhead) and the supervisor's share of a control loop running the
real MultirotorAutopilot.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.flight.multirotor.autopilot import MultirotorAutopilot
from skyherd.runio.runfolder import markdown_table
from skyherd.safety.config import default_envelope_path, load_envelope
from skyherd.safety.drills import DrillParams, toward
from skyherd.safety.envelope import NZ, U
from skyherd.safety.fallback import recovery_target
from skyherd.safety.monitor import make_z
from skyherd.safety.nearest import INF, nearest_point
from skyherd.safety.net import SafetyNet
from skyherd.safety.projection import Projector, qp_cvxpy
from skyherd.safety.supervisor import Supervisor, SupervisorParams


def timed(fn, args_list) -> np.ndarray:
    """Per-call wall times [µs] of fn(*args) over args_list (after 20 warm-up calls)."""
    for a in args_list[:20]:
        fn(*a)
    out = np.empty(len(args_list))
    pc = time.perf_counter_ns
    for i, a in enumerate(args_list):
        t0 = pc()
        fn(*a)
        out[i] = (pc() - t0) / 1e3
    return out


def osqp_as_before(A_u: np.ndarray):
    """The projection as the net solved it before safety.nearest: OSQP set up once over A_u
    (eps 1e-5, polished), per call only q and the upper bounds updated through the extension
    object. Returns solve(A_u, hb, u0) -> u (for timing and comparison only)."""
    import osqp
    import scipy.sparse as sp

    k = len(A_u)
    solver = osqp.OSQP()
    solver.setup(sp.csc_matrix(2.0 * np.eye(3)), np.zeros(3), sp.csc_matrix(A_u),
                 -INF * np.ones(k), INF * np.ones(k), verbose=False, eps_abs=1e-5,
                 eps_rel=1e-5, polishing=True, max_iter=4000, warm_starting=True,
                 check_termination=5)  # fmt: skip
    ext = solver._solver

    def solve(_A: np.ndarray, hb: np.ndarray, u0: np.ndarray) -> np.ndarray:
        ext.update_data_vec(q=-2.0 * u0, l=None, u=hb)
        ext.solve()
        return np.array(ext.solution.x, float)

    return solve


def pct(x: np.ndarray) -> tuple[float, float]:
    return float(np.percentile(x, 50)), float(np.percentile(x, 95))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer samples (~10 s)")
    args = ap.parse_args()
    n = 2_000 if args.quick else 20_000
    rng = np.random.default_rng(0)
    spec, _ = load_envelope(default_envelope_path("quadrotor"))
    env = spec.envelope()
    print(
        f"constraint set {spec.name} {spec.version}: {env.m} rows over z of {NZ}, {len(env.piece_starts)} fence piece(s), {len(env.zone_starts)} exclusion zone(s)"
    )

    zs = np.zeros((n, NZ))
    zs[:, 0:2] = rng.uniform(-80, 80, (n, 2))
    zs[:, 2] = -rng.uniform(5, 60, n)
    zs[:, 3:6] = rng.normal(0, 3, (n, 3))
    zs[:, 6:8] = rng.normal(0, 0.2, (n, 2))
    zs[:, 8:11] = zs[:, 3:6] + rng.normal(0, 1, (n, 3))
    rows = []
    t_mon = timed(env.worst, [(z,) for z in zs])
    rows.append(["monitor check (compiled, A z <= b + union)", *pct(t_mon), n])
    t_np = timed(lambda z: env.worst_of(env.A @ z - env.b), [(z,) for z in zs])
    rows.append(["same check in numpy (reference)", *pct(t_np), n])
    from skyherd.flight.frames import euler_to_quat
    from skyherd.flight.state import VehicleState

    states = [
        VehicleState(
            0.0,
            z[0:3].copy(),
            z[3:6].copy(),
            euler_to_quat(z[6], z[7], 0.0),
            np.zeros(3),
            np.zeros(3),
            False,
        )
        for z in zs[: n // 4]
    ]
    buf = np.zeros(NZ)
    t_state = timed(
        lambda s, u: env.worst(make_z(s, u, buf)), [(s, z[U]) for s, z in zip(states, zs)]
    )
    rows.append(["monitor from a VehicleState (z assembly + check)", *pct(t_state), len(states)])
    bad = [z for z in zs if env.worst(z) > 0][: n // 4]
    t_expl = timed(env.violated, [(z,) for z in bad[: n // 10]])
    rows.append(["explanation of a violation (row names)", *pct(t_expl), len(bad[: n // 10])])

    pr = Projector(env)
    fixable = [z for z in bad if pr.project(z) is not None][: n // 4]
    t_proj = timed(pr.project, [(z, False) for z in fixable])
    rows.append(["projection, exact (safety.nearest)", *pct(t_proj), len(fixable)])
    t_fast = timed(pr.project, [(z, True) for z in fixable])
    problems = []  # the solver's own input: rows, tightened bounds, proposed command
    for z in fixable:
        A, h, _ = pr.bounds(z)
        problems.append((A, np.where(h < INF, h - pr.tighten, INF), z[U].copy()))
    n_closed = sum(pr._single_row(u0, hb) is not None for _, hb, u0 in problems)
    rows.append(
        [
            f"projection, one-row closed form first ({n_closed}/{len(fixable)}), else exact",
            *pct(t_fast),
            len(fixable),
        ]
    )
    t_near = timed(nearest_point, problems)
    rows.append(["  solver alone: safety.nearest", *pct(t_near), len(problems)])
    osqp_solve = osqp_as_before(pr.A_u)
    t_osqp = timed(osqp_solve, problems)
    rows.append(
        ["  solver alone: OSQP set up once (the net's before)", *pct(t_osqp), len(problems)]
    )
    n_rows = sorted({int(np.sum(hb < INF)) for _, hb, _ in problems})
    m = 30 if args.quick else 200
    cv_args = []
    for z in fixable[:m]:
        A, h, _ = pr.bounds(z)
        cv_args.append((A[h < 1e29], h[h < 1e29], z[U]))
    t_cvx = timed(qp_cvxpy, cv_args)
    rows.append(["projection, cvxpy (Clarabel), for comparison", *pct(t_cvx), len(cv_args)])
    pairs = list(zip(fixable[:m], cv_args))
    agree = max(float(np.max(np.abs(pr.project(z, False) - qp_cvxpy(*a)))) for z, a in pairs)
    agree_cf = max(float(np.max(np.abs(pr.project(z, True) - qp_cvxpy(*a)))) for z, a in pairs)
    agree_osqp = max(float(np.max(np.abs(nearest_point(*q) - osqp_solve(*q)))) for q in problems)
    geo = spec.geometry()
    outside = [(geo, z[:3], 6.0) for z in zs if geo.distance_outside(z[:3]) > 0][: n // 10]
    t_rec = timed(recovery_target, outside)
    rows.append(
        ["recovery target (exact, margins halved until they fit)", *pct(t_rec), len(outside)]
    )

    sup = Supervisor(env, SupervisorParams())
    s0 = VehicleState(
        0.0,
        np.array([0.0, 0, -20]),
        np.zeros(3),
        np.array([1.0, 0, 0, 0]),
        np.zeros(3),
        np.zeros(3),
        False,
    )
    sup_args = [(0.02 * k, s0, Setpoint(vel_ned=np.array([0.3, 0.0, 0.0]))) for k in range(n // 4)]
    t_sup = timed(sup.update, sup_args)
    rows.append(["supervisor.update, AI in control (safe action)", *pct(t_sup), len(sup_args)])
    print()
    print(markdown_table(["per call", "p50 µs", "p95 µs", "calls"], rows))
    print(
        f"projection vs cvxpy: max |difference| exact {agree:.2e}, closed form first {agree_cf:.2e} m/s over {len(cv_args)} problems (the 1e-4 tightening of the bounds); p50 speed-up {np.median(t_cvx) / np.median(t_proj):.0f}x (exact), {np.median(t_cvx) / np.median(t_fast):.0f}x (closed form first)"
    )
    print(
        f"solver alone: safety.nearest {np.median(t_near):.1f} µs p50, OSQP {np.median(t_osqp):.1f} µs p50 ({np.median(t_osqp) / np.median(t_near):.2f}x) on {len(problems)} projections over {n_rows} selected rows; max |nearest - OSQP| {agree_osqp:.1e} m/s"
    )
    print(
        f"compiled monitor vs numpy: {np.median(t_np) / np.median(t_mon):.1f}x faster at p50; 10 µs budget met at p95: {pct(t_mon)[1] <= 10}"
    )

    # supervisor overhead in the control loop: real SITL, policy 50 Hz, autopilot 250 Hz; each
    # supervisor.update and each tick of 5 autopilot steps timed in place
    sim_s = 20.0 if args.quick else 120.0
    p = DrillParams()
    vehicle = MultirotorAutopilot()
    vehicle.arm()
    vehicle.takeoff(20.0)
    while vehicle.mode == FlightMode.TAKEOFF:
        vehicle.step()
    vehicle.set_offboard_setpoint(Setpoint(vel_ned=np.zeros(3)))
    vehicle.set_mode(FlightMode.OFFBOARD)
    net = SafetyNet(Supervisor(env, SupervisorParams()))
    net.handover(vehicle.clock.t, vehicle.mode)
    goals = [np.array([40.0, -40.0, -25.0]), np.array([-40.0, 30.0, -30.0])]
    n_sub = round(p.policy_dt_s / vehicle.control_dt)
    t0 = vehicle.clock.t
    t_up, t_ap = [], []
    pc = time.perf_counter_ns
    while vehicle.clock.t - t0 < sim_s:
        t = vehicle.clock.t
        s = vehicle.state
        prop = toward(goals[int((t - t0) // 15) % 2], 5.0, 1.5, p)(t - t0, s)
        a0 = pc()
        net.frame(t)
        net.link(t, t)
        cmd = net.step(t, s, prop).command
        a1 = pc()
        vehicle.set_offboard_setpoint(cmd)
        for _ in range(n_sub):
            vehicle.step()
        a2 = pc()
        t_up.append((a1 - a0) / 1e3)
        t_ap.append((a2 - a1) / 1e3)
    t_up, t_ap = np.array(t_up), np.array(t_ap)
    print(
        f"supervisor during the loop: {net.stats.switches} switches, {net.stats.near} near-active ticks, {net.stats.rejected} rejected"
    )
    print()
    print(
        markdown_table(
            ["control loop, per 20 ms policy tick", "p50 µs", "p95 µs", "mean µs"],
            [
                ["supervisor.update", *pct(t_up), float(t_up.mean())],
                ["5 autopilot steps (MultirotorAutopilot)", *pct(t_ap), float(t_ap.mean())],
            ],
        )
    )
    print(
        f"supervisor overhead: {t_up.mean():.1f} µs per 20 ms tick = {100 * t_up.mean() / 20_000:.3f} % of real time, {100 * t_up.mean() / t_ap.mean():.0f} % of the simulated autopilot's cost ({sim_s:.0f} s simulated, {len(t_up)} ticks)"
    )


if __name__ == "__main__":
    main()
