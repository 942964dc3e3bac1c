"""`skyherd watch`'s frame loop without the command line (perception.watch): real frames on a
real, unconnected Zenoh session's subscriber, fed one per processed frame."""

import csv
import time

import numpy as np

from skyherd.flight.frames import euler_to_quat
from skyherd.groundsim.ugv import UGVModel, UGVStates
from skyherd.perception.camera import CameraParams, UAVPose
from skyherd.perception.render_fast import FastRenderer
from skyherd.perception.transport import (
    FrameSubscriber,
    ZenohParams,
    decode_frame,
    encode_frame,
    open_session,
)
from skyherd.perception.watch import COLUMNS, Watched, WatchParams, strip_image, watch_frames
from skyherd.runio import CsvWriter

POS = np.array([0.0, 0.0, -30.0])
QUAT = euler_to_quat(0.0, 0.0, 0.3)


def _frames(n: int, ugvs_ne: np.ndarray) -> list:
    """n frames of a hovering UAV over the UGVs, 0.1 s of simulation time apart."""
    states = UGVStates(ugvs_ne, np.zeros(len(ugvs_ne)), np.zeros(len(ugvs_ne)))
    image = FastRenderer(CameraParams(), UGVModel()).render(UAVPose(POS, QUAT), states)
    return [decode_frame(encode_frame(k, 0.1 * k, POS, QUAT, image, stream=1)) for k in range(n)]


def test_the_loop_detects_each_frame_writes_its_row_and_every_kth_png(tmp_path):
    session = open_session(ZenohParams())
    sub = FrameSubscriber(session, "uav0")
    frames = _frames(4, np.array([[0.0, 0.0], [6.0, 3.0], [-5.0, 4.0]]))
    sub.on_frame(frames[0])
    rest = iter(frames[1:])

    def next_frame() -> None:  # the next frame arrives once one was processed
        fr = next(rest, None)
        if fr is not None:
            sub.on_frame(fr)

    metrics = CsvWriter(tmp_path / "metrics.csv", COLUMNS)
    seen = Watched()
    p = WatchParams(frames=3, ugvs=3, timeout_s=5.0, save_every=2, show=False)
    watch_frames(sub, p, metrics, tmp_path, lambda: False, seen, next_frame)
    metrics.close()
    session.close()
    assert seen.processed == 3 and seen.counts == [3, 3, 3] and all(seen.all_in)
    header = (tmp_path / "metrics.csv").read_text().splitlines()[0].split(",")
    assert len(header) == len(set(header)) and "all_in_view" in header  # each column once
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert [int(r["seq"]) for r in rows] == [0, 1, 2]
    assert [float(r["t_sim"]) for r in rows] == [0.0, 0.1, 0.2]
    assert all(int(r["count"]) == 3 and float(r["all_in_view"]) == 1.0 for r in rows)
    pngs = sorted(p.name for p in tmp_path.glob("frame_*.png"))
    assert pngs == ["frame_000000.png", "frame_000002.png"]  # every 2nd processed frame
    image, n = strip_image(seen.strip, 2)
    h, w = seen.strip[0][1].shape[:2]
    assert n == 2 and image.shape[1] == 2 * (w // 2) and image.shape[0] > h // 2


def test_the_loop_gives_up_after_the_timeout_and_stops_when_asked(tmp_path):
    session = open_session(ZenohParams())
    sub = FrameSubscriber(session, "uav0")
    metrics = CsvWriter(tmp_path / "metrics.csv", COLUMNS)
    p = WatchParams(frames=5, timeout_s=0.3, show=False)
    t0 = time.monotonic()
    watch_frames(sub, p, metrics, tmp_path, lambda: False, seen := Watched())
    waited = time.monotonic() - t0
    assert seen.processed == 0 and 0.3 <= waited < 2.0
    t0 = time.monotonic()
    p = WatchParams(timeout_s=30.0, show=False)
    watch_frames(sub, p, metrics, tmp_path, lambda: True, Watched())
    assert time.monotonic() - t0 < 0.5
    metrics.close()
    session.close()
