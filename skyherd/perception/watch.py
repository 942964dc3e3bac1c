"""`skyherd watch`'s frame loop: the newest frame of a vehicle's camera each time one arrives
(perception.transport.FrameSubscriber; with the flight key, authentic frames only), the
detector and φ(s) on it, one metrics row per frame, every k-th annotated frame as PNG, and a
strip of annotated frames (red dot = image centre, blue dot = the UGVs' centre of mass, blue
circle = their spread)."""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from skyherd.perception.camera import CameraParams
from skyherd.perception.detector import Detections, Detector, annotate, contact_sheet
from skyherd.perception.features import FEATURE_NAMES
from skyherd.perception.sheet import label, legend
from skyherd.perception.transport import Frame, FrameSubscriber
from skyherd.runio import atomic_write_bytes

COLUMNS = ["seq", "t_sim", "count", "com_u_px", "com_v_px", "radius_px", "latency_ms",
           *FEATURE_NAMES]  # fmt: skip
"""metrics.csv: the frame, its detections, then φ(s) (its all_in_view is the detection's)."""


@dataclass(frozen=True)
class WatchParams:
    frames: int = 100  # frames to process
    ugvs: int = 3  # UGVs in the team
    timeout_s: float = 10.0  # give up after this long without a frame [s of wall time]
    save_every: int = 1  # save every k-th annotated frame as PNG
    show: bool = True  # a window, when a display exists and OpenCV has a GUI


@dataclass
class Watched:
    """What the loop saw: frames processed, UGVs detected and all-in-view per frame, the
    annotated frames with their simulation time (for the strip), the detector last used."""

    processed: int = 0
    counts: list[int] = field(default_factory=list)
    all_in: list[bool] = field(default_factory=list)
    strip: list[tuple[float, np.ndarray]] = field(default_factory=list)
    detector: Detector | None = None


def camera_from(info: dict | None, shape: tuple[int, int]) -> CameraParams:
    """Camera from the camera/info record if one arrived, else defaults at the frame's size."""
    h, w = shape
    if info and info.get("width_px") == w and info.get("height_px") == h:
        return CameraParams(
            width_px=w,
            height_px=h,
            hfov_rad=float(info["hfov_rad"]),
            mount_pitch_rad=float(info.get("mount_pitch_rad", 0.0)),
            mount_offset_frd=tuple(info.get("mount_offset_frd_m", (0.0, 0.0, 0.1))),
        )
    return CameraParams(width_px=w, height_px=h)


def try_show(img: np.ndarray, enabled: bool) -> bool:
    """Show a window when a display exists and OpenCV has a GUI; returns whether it did."""
    if not enabled or not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        cv2.imshow("skyherd watch", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        cv2.waitKey(1)
        return True
    except cv2.error:  # opencv-python-headless: no GUI
        return False


def watch_folder(run, save_every: int):
    """frames/ and metrics.csv in the run folder `run` (runio.Run), described; the metrics
    writer (COLUMNS)."""
    (run.path / "frames").mkdir()
    run.describe("frames", f"annotated frames, PNG (one in every {save_every})")
    run.describe("metrics.csv", "one row per processed frame: seq, sim time, UGVs detected, "
                 "centre of mass, spread, latency, φ(s)")  # fmt: skip
    return run.metrics(COLUMNS)


def watch_frames(
    sub: FrameSubscriber,
    p: WatchParams,
    metrics,
    frames_dir: Path,
    stop: Callable[[], bool],
    seen: Watched,
    on_frame: Callable[[], None] | None = None,
) -> None:
    """Detect on frames until `p.frames` are processed, `p.timeout_s` passes without one, or
    `stop()` (checked between frames); rows to `metrics` (COLUMNS), PNGs into `frames_dir`,
    the tally into `seen`, `on_frame()` after each frame."""
    shown = p.show
    t_last = time.monotonic()
    while seen.processed < p.frames and not stop():
        fr = sub.wait(0.2)
        if fr is None:
            if time.monotonic() - t_last > p.timeout_s:
                break
            continue
        t_last = time.monotonic()
        det_ = seen.detector
        if det_ is None or det_.cam.width_px != fr.image.shape[1]:
            det_ = seen.detector = Detector(camera_from(sub.info, fr.image.shape[:2]), p.ugvs)
        det, img = _process(fr, det_, metrics)
        if seen.processed % p.save_every == 0:
            ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            if ok:
                atomic_write_bytes(frames_dir / f"frame_{fr.seq:06d}.png", png.tobytes())
        seen.strip.append((fr.t_sim, img))
        shown = try_show(img, shown)
        seen.counts.append(det.count)
        seen.all_in.append(det.all_in_view)
        seen.processed += 1
        if on_frame is not None:
            on_frame()


def _process(fr: Frame, det_: Detector, metrics) -> tuple[Detections, np.ndarray]:
    """Detections and φ(s) of one frame into its metrics row; the detections, the annotated
    frame."""
    det = det_.detect(fr.image)
    phi = det_.features(det, -float(fr.pos_ned[2]))
    img = annotate(fr.image, det, scale=2)
    com = det.measure.com_px if det.measure.com_px is not None else (np.nan, np.nan)
    metrics.write({
        "seq": fr.seq, "t_sim": fr.t_sim, "count": det.count, "com_u_px": float(com[0]),
        "com_v_px": float(com[1]), "radius_px": det.measure.radius_px,
        "latency_ms": 1e3 * fr.latency_s, **dict(zip(FEATURE_NAMES, phi.tolist())),
    })  # fmt: skip
    return det, img


def strip_image(strip: list[tuple[float, np.ndarray]], n: int) -> tuple[np.ndarray, int]:
    """At most `n` annotated frames evenly spread over `strip`, half size, each labelled with
    its simulation time, four to a row, over a legend band; the image and the frames on it."""
    idx = np.linspace(0, len(strip) - 1, min(n, len(strip))).round().astype(int)
    tiles = [cv2.resize(strip[i][1], None, fx=0.5, fy=0.5) for i in idx]
    labels = [f"t = {strip[i][0]:.1f} s" for i in idx]
    sheet = contact_sheet(label(tiles, labels), cols=4)
    return np.vstack([sheet, legend(sheet.shape[1], "sim time")]), len(idx)
