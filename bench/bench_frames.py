"""Benchmark: skyherd's camera-frame publisher against raw eclipse-zenoh on the same frames.

    .venv/bin/python bench/bench_frames.py [--frames 150] [--rounds 4] [--size 640x480] [--rate 30]

Run it inside `unshare -n` (a private loopback). A subscriber process (this file with
`--subscriber PORT`) listens as a Zenoh peer (tcp/127.0.0.1, shared memory on: the defaults of
perception.transport) and counts what arrives. Blocks of `--frames` of the same rendered
frames (FastRenderer, a moving UGV team) are published at `--rate` frames per second, each block
by a fresh process (this file with `--block KIND`) so that no kind's allocator state shapes
another's, the kinds alternated (A B C, C B A, ...):

- raw: a plain eclipse-zenoh publisher with the frame publisher's QoS, `put(image.tobytes())`
  (what a user of zenoh-python writes; Zenoh's transport optimisation moves it through shared
  memory);
- skyherd: `FramePublisher.publish`, plain frames (version 5: a CRC of the header, the pixels
  not read), the image copied into the payload that is published (`frame_buffer()`; the
  simulator's renderer draws there instead), the payload copied into a shared-memory buffer;
- skyherd signed: the same with a flight key (version 6: an AES-GMAC pass over the pixels
  under the flight's pixel key and a random IV, BLAKE2b MAC over the header with that digest;
  version 4 made it a Poly1305 pass under a per-frame key).

CPU per frame is the block process's CPU time (`time.process_time`: every thread, Zenoh's
included) over the block, divided by its frames; the copy of the image into the published
buffer (raw: `tobytes`) is counted on both sides. Prints each block (with its minor page faults
per frame), the medians and the ratios to raw.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
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
    from skyherd.perception.transport import open_session, publisher_params

    session = open_session(publisher_params(port))  # listens; each block's process connects
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


def block(kind: str, port: int, w: int, h: int, n: int, rate: float, shm_frames: int) -> dict:
    """One block in this process (a fresh one per block: the allocator's state of one kind
    never shapes another's): connect to the subscriber, warm up, publish `n` frames of `kind`
    at `rate`; CPU ms and minor page faults per frame."""
    import zenoh

    from skyherd.perception.camera import CameraParams
    from skyherd.perception.transport import FramePublisher, open_session, subscriber_params

    images = frames_of(w, h, n)
    session = open_session(subscriber_params(port=port))
    cam = CameraParams(width_px=w, height_px=h)
    pos, quat = np.array([0.0, 0.0, -25.0]), np.array([1.0, 0.0, 0.0, 0.0])
    pub = None
    if kind == "raw":
        raw = session.declare_publisher(RAW_KEY, congestion_control=zenoh.CongestionControl.DROP,
                                        priority=zenoh.Priority.DATA_HIGH, express=True)  # fmt: skip
        matched = lambda: raw.matching_status.matching  # noqa: E731

        def put(k: int, img: np.ndarray) -> None:
            raw.put(img.tobytes())

    else:
        key = os.urandom(32) if kind == "skyherd signed" else None
        pub = FramePublisher(session, VEHICLE, cam, rng=np.random.default_rng(0), key=key,
                             **({} if shm_frames < 0 else {"shm_frames": shm_frames}))  # fmt: skip
        matched = pub.has_subscriber

        def put(k: int, img: np.ndarray) -> None:
            if not hasattr(pub, "frame_buffer"):  # an older tree
                pub.publish(0.1 * k, pos, quat, img)
                return
            buf = pub.frame_buffer()
            buf[...] = img  # the renderer's output lands in the published buffer
            pub.publish(0.1 * k, pos, quat, buf)

    deadline = time.monotonic() + 30
    while not matched():
        if time.monotonic() > deadline:
            raise SystemExit("no subscriber within 30 s")
        time.sleep(0.01)
    for k, img in enumerate(images[:30]):  # warm-up: pools allocated, pages touched
        put(k, img)
    time.sleep(0.2)
    period = 1.0 / rate if rate > 0 else 0.0
    t0, c0 = time.monotonic(), time.process_time()
    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    nxt = t0
    for k, img in enumerate(images):
        put(k, img)
        if period:
            nxt += period
            time.sleep(max(0.0, nxt - time.monotonic()))
    out = {"cpu_ms": (time.process_time() - c0) / n * 1e3, "wall_s": time.monotonic() - t0,
           "faults": (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0) / n,
           "fallbacks": pub.shm_fallbacks if pub is not None else 0}  # fmt: skip
    time.sleep(0.2)  # the last frames leave before the session closes
    session.close()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--frames", type=int, default=150, help="frames per block")
    ap.add_argument("--rounds", type=int, default=4, help="blocks of each kind, alternated")
    ap.add_argument("--size", default="640x480")
    ap.add_argument("--rate", type=float, default=30.0, help="frames per second (0: flat out)")
    ap.add_argument("--port", type=int, default=7471)
    ap.add_argument("--kinds", default="raw,skyherd,skyherd signed", help="comma-separated")
    ap.add_argument(
        "--shm-frames",
        type=int,
        default=-1,
        help="FramePublisher's shm_frames (default: its default, 8; 0: Zenoh's pool)",
    )
    ap.add_argument("--subscriber", type=int, default=None, help=argparse.SUPPRESS)
    ap.add_argument("--block", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.subscriber is not None:
        return subscriber(a.subscriber)
    w, h = (int(x) for x in a.size.lower().split("x"))
    if a.block is not None:
        print(json.dumps(block(a.block, a.port, w, h, a.frames, a.rate, a.shm_frames)))
        return 0
    sub = subprocess.Popen([sys.executable, __file__, "--subscriber", str(a.port)],
                           stdin=subprocess.PIPE)  # fmt: skip
    order = a.kinds.split(",")
    per: dict[str, list[float]] = {k: [] for k in order}
    print(f"## Frame publisher CPU per frame, {a.size} at {a.rate:g} frames/s, "
          f"{a.frames} frames a block, one process per block\n")  # fmt: skip
    print("| round | kind | CPU ms per frame | page faults per frame | shm fallbacks | wall s |")
    print("|---|---|---|---|---|---|")
    try:
        for r in range(a.rounds):
            for kind in order if r % 2 == 0 else order[::-1]:
                out = subprocess.run(
                    [sys.executable, __file__, "--block", kind, "--port", str(a.port),
                     "--frames", str(a.frames), "--size", a.size, "--rate", str(a.rate),
                     "--shm-frames", str(a.shm_frames)],
                    check=True, capture_output=True, text=True,
                )  # fmt: skip
                b = json.loads(out.stdout.strip().splitlines()[-1])
                per[kind].append(b["cpu_ms"])
                print(f"| {r} | {kind} | {b['cpu_ms']:.3f} | {b['faults']:.0f} | "
                      f"{b['fallbacks']} | {b['wall_s']:.2f} |", flush=True)  # fmt: skip
    finally:
        sub.stdin.close()
        sub.wait(timeout=30)
    med = {k: statistics.median(v) for k, v in per.items()}
    print("\n| kind | CPU ms per frame (median) | ratio to raw |")
    print("|---|---|---|")
    for k, v in med.items():
        print(f"| {k} | {v:.3f} | {v / med.get('raw', math.nan):.2f} |")
    print(f"\nload average at the end: {os.getloadavg()[0]:.2f} on {os.cpu_count()} CPUs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
