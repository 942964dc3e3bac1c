"""`skyherd watch`: subscribe to a vehicle's camera frames, detect the UGVs, save the view.

Connects (Zenoh peer, loopback by default) to `skyherd/<vehicle>/camera/frame`, runs the
detector on the newest frame each time one arrives, and writes into `runs/<time>-watch/`:
annotated PNGs (red dot = image centre, blue dot = UGVs' centre of mass, blue circle = spread),
`strip.png` (a frame strip), `metrics.csv` (one row per processed frame: counts, φ(s),
latency), `config.json` and `summary.md` (link counts and detection figures). A window shows
the annotated view only when a display exists and OpenCV has a GUI.

Exit codes: 0 frames were processed; 1 no frame arrived before --timeout; 2 bad usage.
"""

from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from perception.camera import CameraParams
from perception.detector import Detector, annotate, contact_sheet, write_png
from perception.features import FEATURE_NAMES, FeatureParams
from perception.transport import (
    FrameSubscriber,
    ZenohParams,
    open_session,
    subscriber_params,
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--vehicle", default="uav0", help="vehicle name in the key (uav0)")
    parser.add_argument(
        "--connect",
        default="tcp/127.0.0.1:7447",
        help="Zenoh endpoint of the frame source (tcp/127.0.0.1:7447)",
    )
    parser.add_argument(
        "--zenoh-config", default=None, help="Zenoh JSON5 config file (replaces --connect)"
    )
    parser.add_argument("--frames", type=int, default=100, help="frames to process (100)")
    parser.add_argument(
        "--runs-dir", "--out", dest="runs_dir", default="runs",
        help="where run folders go (runs); --out is the older name",
    )  # fmt: skip
    parser.add_argument("--ugvs", type=int, default=3, help="UGVs in the team (3)")
    parser.add_argument(
        "--timeout", type=float, default=10.0, help="give up after this long without a frame [s]"
    )
    parser.add_argument(
        "--save-every", type=int, default=1, help="save every k-th annotated frame as PNG (1)"
    )
    parser.add_argument("--strip", type=int, default=8, help="frames in strip.png (8)")
    parser.add_argument("--no-show", action="store_true", help="never open a window")


def _check(args: argparse.Namespace) -> None:
    from scripts.cli import UsageError

    if args.frames < 1:
        raise UsageError("--frames must be >= 1")
    if args.ugvs < 1:
        raise UsageError("--ugvs must be >= 1")
    if args.save_every < 1 or args.strip < 0:
        raise UsageError("--save-every must be >= 1 and --strip >= 0")
    if not args.timeout > 0:
        raise UsageError("--timeout must be > 0 seconds")
    if args.zenoh_config and not os.path.exists(args.zenoh_config):
        raise UsageError(f"Zenoh config {args.zenoh_config} not found: give an existing file")


def _camera_from(info: dict | None, shape: tuple[int, int]) -> CameraParams:
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


def _try_show(img: np.ndarray, enabled: bool) -> bool:
    """Show a window when a display exists and OpenCV has a GUI; returns whether it did."""
    if not enabled or not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return False
    try:
        cv2.imshow("skyherd watch", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
        cv2.waitKey(1)
        return True
    except cv2.error:  # opencv-python-headless: no GUI
        return False


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from runio.runfolder import RunFolder, atomic_write_bytes, markdown_table
    from scripts.cli import UsageError

    _check(args)
    zp = (
        ZenohParams(config_file=args.zenoh_config)
        if args.zenoh_config
        else subscriber_params(args.connect)
    )
    try:
        session = open_session(zp)
    except ValueError as e:
        raise UsageError(f"{e}; check --connect / --zenoh-config") from e
    rf = RunFolder("watch", root=args.runs_dir)
    rf.write_config({"args": {k: v for k, v in vars(args).items() if not k.startswith("_")},
                     "zenoh": zp, "feature_params": FeatureParams()})  # fmt: skip
    (rf.path / "frames").mkdir()
    metrics = rf.metrics(
        ["seq", "t_sim", "count", "all_in_view", "com_u_px", "com_v_px", "radius_px",
         "latency_ms", *FEATURE_NAMES]
    )  # fmt: skip
    sub = FrameSubscriber(session, args.vehicle)
    detector: Detector | None = None
    shown = not args.no_show
    processed, counts, all_in, strip = 0, [], [], []
    t_last = time.monotonic()
    bar = tqdm(total=args.frames, desc="watch", unit="frame", disable=None)
    try:
        while processed < args.frames:
            fr = sub.wait(0.2)
            if fr is None:
                if time.monotonic() - t_last > args.timeout:
                    break
                continue
            t_last = time.monotonic()
            if detector is None or detector.cam.width_px != fr.image.shape[1]:
                cam = _camera_from(sub.info, fr.image.shape[:2])
                detector = Detector(cam, args.ugvs)
            det = detector.detect(fr.image)
            phi = detector.features(det, -float(fr.pos_ned[2]))
            img = annotate(fr.image, det, scale=2)
            com = det.measure.com_px if det.measure.com_px is not None else (np.nan, np.nan)
            metrics.write({
                "seq": fr.seq, "t_sim": fr.t_sim, "count": det.count,
                "all_in_view": int(det.all_in_view), "com_u_px": float(com[0]),
                "com_v_px": float(com[1]), "radius_px": det.measure.radius_px,
                "latency_ms": 1e3 * fr.latency_s, **dict(zip(FEATURE_NAMES, phi.tolist())),
            })  # fmt: skip
            if processed % args.save_every == 0:
                ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
                if ok:
                    atomic_write_bytes(
                        rf.path / "frames" / f"frame_{fr.seq:06d}.png", png.tobytes()
                    )
            strip.append(img)
            shown = _try_show(img, shown)
            counts.append(det.count)
            all_in.append(det.all_in_view)
            processed += 1
            bar.update(1)
    except KeyboardInterrupt:
        pass
    finally:
        bar.close()
        stats = sub.stats
        sub.close()
        session.close()
        metrics.close()
    if args.strip and strip:
        idx = np.linspace(0, len(strip) - 1, min(args.strip, len(strip))).round().astype(int)
        tiles = [cv2.resize(strip[i], None, fx=0.5, fy=0.5) for i in idx]
        write_png(rf.path / "strip.png", contact_sheet(tiles, cols=4))
    lat = np.array(stats.latencies_s) * 1e3
    rows = [[k, v] for k, v in stats.as_dict().items()]
    rows += [
        ["processed", processed],
        ["mean UGVs detected", float(np.mean(counts)) if counts else 0.0],
        ["all in view (fraction)", float(np.mean(all_in)) if all_in else 0.0],
        ["latency p50 [ms]", float(np.percentile(lat, 50)) if lat.size else float("nan")],
        ["latency p95 [ms]", float(np.percentile(lat, 95)) if lat.size else float("nan")],
    ]
    table = markdown_table(["quantity", "value"], rows)
    cam_line = ""
    if detector is not None:
        cam_line = f"Camera: {detector.cam}\n\nDetector: {detector.p}\n\n"
    rf.write_summary(
        f"# skyherd watch {args.vehicle}\n\n{table}\n{cam_line}Run folder: {rf.path}\n"
    )
    print(table)
    print(f"run folder: {rf.path}")
    if processed == 0:
        print(f"skyherd watch: no frame on skyherd/{args.vehicle}/camera/frame within "
              f"{args.timeout:g} s (is a flight publishing? --connect {args.connect})")  # fmt: skip
        return 1
    return 0
