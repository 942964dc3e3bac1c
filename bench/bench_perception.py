"""Benchmark: renderers, detector, detector accuracy, Zenoh link, closed-loop real-time factor.

    .venv/bin/python bench/bench_perception.py [--quick]

Prints markdown tables:
1. frames/s of the fast (OpenCV) and PyBullet (TinyRenderer) renderers at 320×240 and 640×480;
2. detector frames/s (goal ≥ 1000 at 320×240);
3. detector accuracy against ground truth over random scenes from both renderers (1000 frames
   each; 200 with --quick): median centroid error (goal ≤ 2 px), spread radius (≤ 3 px);
4. Zenoh between two processes (`skyherd camstream` → this process) on loopback: latency
   p50/p95 at a paced 30 frames/s, and frames/s delivered when the source sends flat out;
5. the ground world alone (kinematic, PyBullet box, PyBullet husky): real-time factor;
6. real-time factor of the loop ground world step + render + detect + φ(s), camera at 10 and
   30 Hz of simulation time (goals ≥ 50× fast renderer, ≥ 5× PyBullet pixels).

Rates are given per wall-clock second and per second of this process's CPU time: on a shared
machine other processes steal the wall clock, the CPU figure is what the code itself costs.
"""

from __future__ import annotations

import argparse
import os
import socket
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from skyherd.flight.frames import euler_to_quat  # noqa: E402
from skyherd.groundsim.behaviours import DriveParams, make_behaviour, triangle_offsets  # noqa: E402
from skyherd.groundsim.kinematic import KinematicWorld  # noqa: E402
from skyherd.groundsim.ugv import UGVModel, initial_states  # noqa: E402
from skyherd.groundsim.world import GroundWorld, WorldParams  # noqa: E402
from skyherd.perception.camera import CameraParams, UAVPose  # noqa: E402
from skyherd.perception.detector import Detector  # noqa: E402
from skyherd.perception.evaluate import SceneParams, evaluate, random_scene  # noqa: E402
from skyherd.perception.render_bullet import BulletRenderer, BulletRenderParams  # noqa: E402
from skyherd.perception.render_fast import FastRenderer  # noqa: E402
from skyherd.perception.transport import FrameSubscriber, open_session, subscriber_params  # noqa: E402
from skyherd.runio.runfolder import markdown_table  # noqa: E402

SIZES = ((320, 240), (640, 480))
MODEL = UGVModel()


def new_world(n=3) -> GroundWorld:
    return GroundWorld(
        initial_states(triangle_offsets(n)), make_behaviour("route", n, np.random.default_rng(0))
    )


def rate(fn, items) -> tuple[float, float]:
    """Calls per second of fn over items: (wall clock, this process's CPU time)."""
    w0, c0 = time.perf_counter(), time.process_time()
    for it in items:
        fn(it)
    w1, c1 = time.perf_counter(), time.process_time()
    return len(items) / (w1 - w0), len(items) / max(c1 - c0, 1e-9)


def bench_renderers(n_fast: int, n_bullet: int) -> list[list]:
    rows = []
    worlds = [new_world(), new_world()]
    for w, h in SIZES:
        cam = CameraParams(width_px=w, height_px=h)
        rng = np.random.default_rng(0)
        scenes = [random_scene(cam, MODEL, SceneParams(), rng) for _ in range(max(n_fast, 50))]
        fast = FastRenderer(cam, MODEL)
        bullet = BulletRenderer(worlds[0], cam)
        bullet_full = BulletRenderer(worlds[1], cam, BulletRenderParams(composite_ground=False))
        det = Detector(cam, 3)
        frames = [fast.render(u, s) for u, s in scenes[:50]]
        rf = rate(lambda us, r=fast: r.render(*us), scenes[:n_fast])
        rb = rate(lambda us, r=bullet: r.render(*us), scenes[:n_bullet])
        rbf = rate(lambda us, r=bullet_full: r.render(*us), scenes[: max(5, n_bullet // 3)])
        rd = rate(det.detect, [frames[k % len(frames)] for k in range(20 * len(frames))])
        rows.append([f"{w}x{h}", *rf, *rb, *rbf, *rd])
    for wd in worlds:
        wd.close()
    return rows


def bench_accuracy(n_frames: int) -> list[list]:
    cam = CameraParams()
    det = Detector(cam, 3)
    world = new_world()
    rows = []
    for name, r, seed in (
        ("fast (OpenCV)", FastRenderer(cam, MODEL), 1),
        ("PyBullet TinyRenderer", BulletRenderer(world, cam), 2),
    ):
        s = evaluate(r, det, cam, MODEL, n_frames, np.random.default_rng(seed)).summary()
        rows.append([
            name, s["frames"], s["centroid_median_px"], s["centroid_p95_px"],
            s["com_median_px"], s["radius_median_px"], s["radius_p95_px"], s["count_exact"],
        ])  # fmt: skip
    world.close()
    return rows


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def zenoh_run(size: str, frames: int, rate: float) -> dict:
    """Frames from a camstream process to this one; latency and delivered frames/s."""
    port = _free_port()
    session = open_session(subscriber_params(port=port))
    sub = FrameSubscriber(session, "bench")
    src = subprocess.Popen(
        [sys.executable, "-m", "skyherd.scripts.cli", "camstream", "--vehicle", "bench", "--port", str(port),
         "--frames", str(frames), "--rate", str(rate), "--size", size, "--static",
         "--wait-s", "10"],
        stderr=subprocess.DEVNULL,
    )  # fmt: skip
    first = last = None
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        f = sub.wait(0.5)
        if f is not None:
            first = first or time.perf_counter()
            last = time.perf_counter()
        elif src.poll() is not None:
            break
    src.wait(timeout=30)
    s = sub.stats
    sub.close()
    session.close()
    lat = np.array(s.latencies_s) * 1e3
    return {
        "received": s.received,
        "lost": s.lost,
        "p50_ms": float(np.percentile(lat, 50)) if lat.size else float("nan"),
        "p95_ms": float(np.percentile(lat, 95)) if lat.size else float("nan"),
        "fps": (s.received - 1) / (last - first) if first and last and last > first else 0.0,
    }


def bench_zenoh(quick: bool) -> list[list]:
    rows = []
    n_paced = 150 if quick else 300
    n_flat = 300 if quick else 1000
    for size in ("320x240", "640x480"):
        paced = zenoh_run(size, n_paced, 30.0)
        flat = zenoh_run(size, n_flat, 0.0)
        rows.append([
            size, paced["p50_ms"], paced["p95_ms"], paced["lost"], flat["fps"],
            flat["received"], flat["lost"], flat["p50_ms"],
        ])  # fmt: skip
    return rows


def loop_rtf(world_kind: str, renderer_kind: str, cam_hz: float, sim_s: float) -> tuple:
    """Ground world + render + detect + φ(s) at `cam_hz`: simulated s per (wall s, CPU s)."""
    cam = CameraParams()
    drive = DriveParams()
    beh = make_behaviour("route", 3, np.random.default_rng(0), drive)
    st = initial_states(triangle_offsets(3))
    gw = GroundWorld(st, beh, drive) if world_kind == "pybullet" else None
    world = gw if gw is not None else KinematicWorld(st, beh, drive)
    if renderer_kind == "pybullet":
        bw = gw if gw is not None else new_world()
        renderer = BulletRenderer(bw, cam)
    else:
        renderer = FastRenderer(cam, MODEL)
    det = Detector(cam, 3)
    dt = 1.0 / cam_hz
    q = euler_to_quat(0.0, 0.0, 0.0)
    t = 0.0
    t0, c0 = time.perf_counter(), time.process_time()
    while t < sim_s:
        states = world.step(t, dt)
        c = states.pos_ne.mean(axis=0)
        uav = UAVPose(np.array([c[0], c[1], -30.0]), q)
        d = det.detect(renderer.render(uav, states))
        det.features(d, 30.0)
        t += dt
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    if gw is not None:
        gw.close()
    elif renderer_kind == "pybullet":
        bw.close()
    return t / wall, t / cpu


def bench_worlds(quick: bool) -> list[list]:
    """Ground world alone, 3 UGVs on the route, 20 Hz steps: real-time factors."""
    drive = DriveParams()
    sim_s = 20.0 if quick else 60.0
    rows = []
    for name in ("kinematic", "box", "husky"):
        beh = make_behaviour("route", 3, np.random.default_rng(0), drive)
        st = initial_states(triangle_offsets(3))
        if name == "kinematic":
            world = KinematicWorld(st, beh, drive)
        else:
            world = GroundWorld(st, beh, drive, WorldParams(ugv_model=name))
        n = int(round((sim_s if name != "husky" else sim_s / 4) / 0.05))
        w0, c0 = time.perf_counter(), time.process_time()
        for i in range(n):
            world.step(i * 0.05, 0.05)
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        if name != "kinematic":
            world.close()
        rows.append([name, n * 0.05, n * 0.05 / wall, n * 0.05 / cpu])
    return rows


def bench_loop(quick: bool) -> list[list]:
    sim_fast = 30.0 if quick else 60.0
    sim_bullet = 10.0 if quick else 20.0
    rows = []
    for world_kind in ("kinematic", "pybullet"):
        for rk, sim_s, goal in (("fast", sim_fast, 50), ("pybullet", sim_bullet, 5)):
            for hz in (10.0, 30.0):
                rtf, rtf_cpu = loop_rtf(world_kind, rk, hz, sim_s)
                met = "yes" if rtf >= goal else ("CPU only" if rtf_cpu >= goal else "no")
                rows.append([world_kind, rk, hz, rtf, rtf_cpu, f">= {goal}x", met])
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer frames (about 30 s)")
    a = ap.parse_args(argv)
    t_start = time.perf_counter()
    print("## Renderers and detector (frames/s)\n")
    rows = bench_renderers(300 if a.quick else 1000, 30 if a.quick else 100)
    print(markdown_table(
        ["size", "fast render", "(CPU)", "PyBullet render", "(CPU)", "PyBullet, ground drawn",
         "(CPU)", "detector", "(CPU)"], rows))  # fmt: skip
    print("## Detector accuracy against ground truth (3 UGVs apart, 10-45 m, tilt <= 0.3 rad)\n")
    rows = bench_accuracy(200 if a.quick else 1000)
    print(markdown_table(
        ["renderer", "frames", "centroid median px", "centroid p95 px", "CoM median px",
         "radius median px", "radius p95 px", "exact count"], rows))  # fmt: skip
    print("## Zenoh, two processes on loopback (peer, tcp/127.0.0.1, raw RGB)\n")
    rows = bench_zenoh(a.quick)
    print(markdown_table(
        ["size", "p50 ms @30 fps", "p95 ms @30 fps", "lost @30", "frames/s flat out",
         "received", "lost (dropped)", "p50 ms flat out"], rows))  # fmt: skip
    print("## Ground world alone (3 UGVs, 20 Hz steps, real-time factor)\n")
    print(markdown_table(["world", "sim s", "RTF", "RTF (CPU)"], bench_worlds(a.quick)))
    print("## Closed loop: ground world + render + detect + phi(s) (real-time factor)\n")
    rows = bench_loop(a.quick)
    print(
        markdown_table(
            ["ground world", "renderer", "camera Hz", "RTF", "RTF (CPU)", "goal", "met"], rows
        )
    )
    print(f"load average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs "
          "(CPU columns: per second of this process's own CPU time)")  # fmt: skip
    print(f"bench time {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
