"""Benchmark: skyherd's camera-frame publisher against raw eclipse-zenoh on the same frames.

    .venv/bin/python bench/bench_frames.py [--frames 150] [--rounds 4] [--size 640x480] [--rate 30]

Run it inside `unshare -n` (a private loopback). A subscriber process (this file with
`--subscriber PORT`) connects to this process's Zenoh peer (tcp/127.0.0.1, shared memory on,
the defaults of perception.transport) and counts what arrives. This process publishes the same
pre-rendered frames (FastRenderer, a moving UGV team) at `--rate` frames per second in
alternated blocks of `--frames`:

- raw: a plain eclipse-zenoh publisher with the frame publisher's QoS, `put(image.tobytes())`
  (what a user of zenoh-python writes; Zenoh's transport optimisation moves it through shared
  memory);
- skyherd: `FramePublisher.publish` unsigned (version 1) — the image copied into the buffer that
  is published, as the simulator's camera does (`frame_buffer()`);
- skyherd signed: the same with the flight key (SHA-256 of the pixels once, MAC over the header).

CPU per frame is this process's CPU time (`time.process_time`: every thread, Zenoh's included)
over a block, divided by its frames; the block's copy of the image into the published buffer is
counted on both sides. Prints each block, the medians and the ratios skyherd / raw.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

RAW_KEY = "bench/raw/frame"
VEHICLE = "bench"


def subscriber(port: int) -> int:
    from skyherd.perception.transport import open_session, subscriber_params

    session = open_session(subscriber_params(port=port))
    n = {"raw": 0, "frames": 0}

    def raw(sample) -> None:
        n["raw"] += 1

    def frame(sample) -> None:
        n["frames"] += 1

    session.declare_subscriber(RAW_KEY, raw)
    session.declare_subscriber(f"skyherd/{VEHICLE}/camera/frame", frame)
    try:
        sys.stdin.read()  # until the parent closes the pipe
    finally:
        print(f"subscriber: {n}", file=sys.stderr)
        session.close()
    return 0


def frames_of(w: int, h: int, n: int) -> list[np.ndarray]:
    from skyherd.flight.frames import euler_to_quat
    from skyherd.groundsim.behaviours import DriveParams, make_behaviour, triangle_offsets
    from skyherd.groundsim.kinematic import KinematicWorld
    from skyherd.groundsim.ugv import UGVModel, initial_states
    from skyherd.perception.camera import CameraParams, UAVPose
    from skyherd.perception.render_fast import FastRenderer

    cam = CameraParams(width_px=w, height_px=h)
    world = KinematicWorld(initial_states(triangle_offsets(3)),
                           make_behaviour("route", 3, np.random.default_rng(0)), DriveParams())  # fmt: skip
    r = FastRenderer(cam, UGVModel())
    uav = UAVPose(np.array([0.0, 0.0, -25.0]), euler_to_quat(0.0, 0.0, 0.0))
    return [r.render(uav, world.step(0.1 * k, 0.1)) for k in range(n)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--frames", type=int, default=150, help="frames per block")
    ap.add_argument("--rounds", type=int, default=4, help="blocks of each kind, alternated")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--rate", type=float, default=30.0, help="frames per second (0: flat out)")
    ap.add_argument("--port", type=int, default=7471)
    ap.add_argument("--subscriber", type=int, default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.subscriber is not None:
        return subscriber(a.subscriber)
    import zenoh

    from skyherd.perception.camera import CameraParams
    from skyherd.perception.transport import FramePublisher, open_session, publisher_params

    w, h = (int(x) for x in a.size.lower().split("x"))
    images = frames_of(w, h, a.frames)
    session = open_session(publisher_params(a.port))
    sub = subprocess.Popen([sys.executable, __file__, "--subscriber", str(a.port)],
                           stdin=subprocess.PIPE)  # fmt: skip
    cam = CameraParams(width_px=w, height_px=h)
    rng = np.random.default_rng(0)
    plain = FramePublisher(session, VEHICLE, cam, rng=rng)
    signed = FramePublisher(session, VEHICLE, cam, rng=rng, key=os.urandom(32))
    raw = session.declare_publisher(RAW_KEY, congestion_control=zenoh.CongestionControl.DROP,
                                    priority=zenoh.Priority.DATA_HIGH, express=True)  # fmt: skip
    deadline = time.monotonic() + 30
    while not (raw.matching_status.matching and plain.has_subscriber()):
        if time.monotonic() > deadline:
            raise SystemExit("no subscriber within 30 s")
        time.sleep(0.01)
    pos, quat = np.array([0.0, 0.0, -25.0]), np.array([1.0, 0.0, 0.0, 0.0])

    def put_raw(k: int, img: np.ndarray) -> None:
        raw.put(img.tobytes())

    def put_with(pub: FramePublisher):
        def put(k: int, img: np.ndarray) -> None:
            if not hasattr(pub, "frame_buffer"):  # an older tree (--baseline)
                pub.publish(0.1 * k, pos, quat, img)
                return
            buf = pub.frame_buffer()
            buf[...] = img  # the renderer's output lands in the published buffer
            pub.publish(0.1 * k, pos, quat, buf)

        return put

    kinds = {"raw": put_raw, "skyherd": put_with(plain), "skyherd signed": put_with(signed)}
    for _ in range(2):  # warm-up: pools allocated, pages touched
        for put in kinds.values():
            for k, img in enumerate(images[:20]):
                put(k, img)
    per: dict[str, list[float]] = {k: [] for k in kinds}
    order = list(kinds)
    print(
        f"## Frame publisher CPU per frame, {a.size} at {a.rate:g} frames/s, {a.frames} frames a block\n"
    )
    print("| round | kind | CPU ms per frame | wall s |")
    print("|---|---|---|---|")
    for r in range(a.rounds):
        for kind in order if r % 2 == 0 else order[::-1]:
            put = kinds[kind]
            period = 1.0 / a.rate if a.rate > 0 else 0.0
            t0, c0 = time.monotonic(), time.process_time()
            nxt = t0
            for k, img in enumerate(images):
                put(k, img)
                if period:
                    nxt += period
                    time.sleep(max(0.0, nxt - time.monotonic()))
            c = (time.process_time() - c0) / len(images)
            per[kind].append(c)
            print(f"| {r} | {kind} | {c * 1e3:.3f} | {time.monotonic() - t0:.2f} |", flush=True)
    med = {k: statistics.median(v) for k, v in per.items()}
    print("\n| kind | CPU ms per frame (median) | ratio to raw |")
    print("|---|---|---|")
    for k, v in med.items():
        print(f"| {k} | {v * 1e3:.3f} | {v / med['raw']:.2f} |")
    print(
        f"\nshared-memory fallbacks: unsigned {plain.shm_fallbacks}, signed {signed.shm_fallbacks}"
    )
    print(f"load average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    sub.stdin.close()
    sub.wait(timeout=30)
    for p in (plain, signed):
        p.close()
    raw.undeclare()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
