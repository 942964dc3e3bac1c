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
import signal
import time

import cv2
import numpy as np

from skyherd.perception.camera import CameraParams
from skyherd.perception.detector import Detector, annotate, contact_sheet, write_png
from skyherd.perception.features import FEATURE_NAMES, FeatureParams
from skyherd.perception.sheet import label, legend
from skyherd.perception.transport import (
    FrameSubscriber,
    ZenohParams,
    open_session,
    subscriber_params,
)
from skyherd.runio import ports


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--vehicle", default="uav0", help="vehicle name in the key")
    parser.add_argument(
        "--connect",
        default=None,
        metavar="ADDRESS",
        help="the frame source, in the address syntax of every command (tcp:HOST:PORT; "
        f"Zenoh's tcp/HOST:PORT is accepted too) (default: {ports.ZENOH_ADDRESS_HELP} for --instance N)",
    )
    parser.add_argument("--instance", type=int, default=0, metavar="N",
                        help=f"watch the flight of vehicle instance N in [0, {ports.MAX_INSTANCE}] "
                        f"(`skyherd fly/sim --instance N`): its simulator's {ports.ZENOH_PORT_HELP} on "
                        f"{ports.LOOPBACK}")  # fmt: skip
    parser.add_argument(
        "--zenoh-config", default=None, help="Zenoh JSON5 config file (replaces --connect)"
    )
    parser.add_argument("--signing-key", default=None, metavar="FILE",
                        help="the flight's key file (32 bytes: `skyherd fly --signing-key FILE`, or the "
                        "per-run <run>/signing.key): take only authentic frames and records, refuse "
                        "(count) plain or forged ones (default: none, frames are shown unchecked)")  # fmt: skip
    parser.add_argument("--frames", type=int, default=100, help="frames to process")
    parser.add_argument(
        "--runs-dir", "--out", dest="runs_dir", default="runs",
        help="where run folders go; --out is the older name",
    )  # fmt: skip
    parser.add_argument("--ugvs", type=int, default=3, help="UGVs in the team")
    parser.add_argument(
        "--timeout", type=float, default=10.0, help="give up after this long without a frame [s]"
    )
    parser.add_argument(
        "--save-every", type=int, default=1, help="save every k-th annotated frame as PNG"
    )
    parser.add_argument("--strip", type=int, default=8, help="frames in strip.png")
    parser.add_argument("--no-show", action="store_true", help="never open a window")
    parser.add_argument(
        "--mcap", action=argparse.BooleanOptionalAction, default=True,
        help="record the flight seen on Zenoh (frames, poses, UGVs, decisions, safety events, "
        "clock) as flight.mcap in the run folder, for Foxglove / PlotJuggler",
    )  # fmt: skip
    parser.add_argument(
        "--foxglove", type=int, default=None, metavar="PORT",
        help="also serve the flight live to Foxglove at ws://127.0.0.1:PORT",
    )  # fmt: skip


def _check(args: argparse.Namespace) -> None:
    from skyherd.scripts.cli import UsageError

    try:
        ports.check_instance(args.instance)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if args.connect is not None and args.instance != 0:
        raise UsageError(f"--connect {args.connect} and --instance {args.instance} both say where "
                         "the frames come from: give one")  # fmt: skip
    if args.connect is None and not args.zenoh_config:
        args.connect = ports.zenoh_address(args.instance)
    if args.frames < 1:
        raise UsageError("--frames must be >= 1")
    if args.ugvs < 1:
        raise UsageError("--ugvs must be >= 1")
    if args.save_every < 1 or args.strip < 0:
        raise UsageError("--save-every must be >= 1 and --strip >= 0")
    if not args.timeout > 0:
        raise UsageError("--timeout must be > 0 seconds")
    if args.foxglove is not None and not 0 < args.foxglove < 65536:
        raise UsageError("--foxglove PORT must be 1..65535")
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


def zenoh_reason(e: Exception) -> str:
    """A Zenoh error as one readable line (its message without Rust source locations)."""
    from skyherd.perception.transport import zenoh_error_text

    return zenoh_error_text(e)


def _session(args: argparse.Namespace):
    from skyherd.runio.address import AddressError, zenoh_endpoint
    from skyherd.scripts.cli import UsageError

    if args.zenoh_config:
        zp = ZenohParams(config_file=args.zenoh_config)
    else:
        try:
            zp = subscriber_params(zenoh_endpoint(args.connect))
        except AddressError as e:
            raise UsageError(f"--connect {e}") from e
    try:
        return zp, open_session(zp)
    except ValueError as e:
        where = (
            f"--zenoh-config {args.zenoh_config}"
            if args.zenoh_config
            else f"--connect {args.connect}"
        )
        raise UsageError(f"cannot open a Zenoh session ({where}): {zenoh_reason(e)}") from e


class CtrlC:
    """SIGINT (Ctrl-C) while `skyherd watch` runs: noted (`requested`), never raised where
    it lands.

    watch takes SIGINT for the whole command, from before its Zenoh session opens until its
    run folder is written, whatever the process inherited. A background job of a
    non-interactive shell (`cmd &` in a script) starts with SIGINT ignored; watch used to take
    it for its frame loop only, so a Ctrl-C during start-up (even just after metrics.csv
    appeared) was lost and watch waited on until --timeout (the suite saw no exit 120 s after
    SIGINT, --timeout 300). The flag is checked once the session is open and between frames:
    the KeyboardInterrupt that ends the run is raised outside every lock and Zenoh call, and a
    second Ctrl-C cannot cut the ending (session closed, summary.md) half-way. A plain
    attribute, no lock: a handler may run inside another one."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, signum, frame) -> None:
        self.requested = True

    def check(self) -> None:
        if self.requested:
            raise KeyboardInterrupt


def flight_key(args: argparse.Namespace) -> bytes | None:
    """The flight key (--signing-key), None without one; a bad file is a UsageError."""
    from skyherd.flight.mavlink.signing import SigningError, load_key
    from skyherd.scripts.cli import UsageError

    if not args.signing_key:
        return None
    try:
        return load_key(args.signing_key)
    except SigningError as e:
        raise UsageError(f"--signing-key: {e}") from None


def run(args: argparse.Namespace) -> int:
    _check(args)
    key = flight_key(args)
    ctrl_c = CtrlC()
    prev = signal.signal(signal.SIGINT, ctrl_c)
    try:
        zp, session = _session(args)
        try:
            ctrl_c.check()  # during the session's opening: no run folder
            return _watch(args, zp, session, ctrl_c, key)
        finally:
            # on every ending, however early (closing twice is harmless): its subscribers'
            # callback threads are not daemons, and the exit waits for them
            session.close()
    finally:
        signal.signal(signal.SIGINT, prev)


def _watch(
    args: argparse.Namespace, zp: ZenohParams, session, ctrl_c: CtrlC, key: bytes | None
) -> int:
    from tqdm import tqdm

    from skyherd.runio import RunFolder, markdown_table

    sub = FrameSubscriber(session, args.vehicle, key=key)
    st = {"processed": 0, "counts": [], "all_in": [], "strip": [], "detector": None}

    def finish() -> None:
        """Summary, strip.png: from what was received, on every ending (Ctrl-C too)."""
        stats = sub.stats
        sub.close()
        session.close()
        if args.strip and st["strip"]:
            strip = st["strip"]
            idx = np.linspace(0, len(strip) - 1, min(args.strip, len(strip))).round().astype(int)
            tiles = [cv2.resize(strip[i][1], None, fx=0.5, fy=0.5) for i in idx]
            labels = [f"t = {strip[i][0]:.1f} s" for i in idx]
            sheet = contact_sheet(label(tiles, labels), cols=4)
            write_png(run.file("strip.png"), np.vstack([sheet, legend(sheet.shape[1], "sim time")]))
            run.describe("strip.png", f"{len(idx)} annotated frames, sim time on each (red dot "
                         "image centre, blue dot UGVs' centre of mass, blue circle their spread)")  # fmt: skip
        lat = np.array(stats.latencies_s) * 1e3
        counts, all_in = st["counts"], st["all_in"]
        rows = [[k, v] for k, v in stats.as_dict().items()]
        rows += [
            ["processed", st["processed"]],
            ["mean UGVs detected", float(np.mean(counts)) if counts else None],
            ["all in view (fraction)", float(np.mean(all_in)) if all_in else None],
            ["latency p50 [ms]", float(np.percentile(lat, 50)) if lat.size else None],
            ["latency p95 [ms]", float(np.percentile(lat, 95)) if lat.size else None],
        ]
        table = markdown_table(["quantity", "value"], rows, missing="no frame was processed")
        det = st["detector"]
        cam_line = f"Camera: {det.cam}\n\nDetector: {det.p}\n" if det is not None else ""
        rec_line = ""
        if st.get("recorder") is not None and args.mcap:
            counts = st["recorder"].log.counts
            rec_line = (f"flight.mcap: {sum(counts.values())} messages on {len(counts)} channels "
                        f"({', '.join(f'{k} {n}' for k, n in sorted(counts.items()))}).\n\n")  # fmt: skip
        checked = (f"authenticated with the flight key ({args.signing_key}): {stats.refused} refused"
                   if key is not None else "not authenticated (no --signing-key): any publisher's are shown")  # fmt: skip
        run.summary(f"Frames of `skyherd/{args.vehicle}/camera/frame`, {checked}.\n\n"
                    f"{table}\n{rec_line}{cam_line}")  # fmt: skip
        print(table)
        print(f"run folder: {run.path}")

    live = None
    if args.foxglove is not None:
        from skyherd.record import LiveServer
        from skyherd.scripts.cli import UsageError

        try:
            live = LiveServer(args.foxglove)
        except OSError as e:
            session.close()
            raise UsageError(f"--foxglove {args.foxglove}: {e}") from e
        print(f"Foxglove: open ws://127.0.0.1:{live.port}")
    with RunFolder.open("watch", args, root=args.runs_dir) as run:
        run.config(zenoh=zp, feature_params=FeatureParams())
        if args.mcap or live is not None:
            path = run.file("flight.mcap") if args.mcap else None
            rec = run.closing(_recorder(session, args.vehicle, path, live, key))
            st["recorder"] = rec
        (run.path / "frames").mkdir()
        run.describe("frames", f"annotated frames, PNG (one in every {args.save_every})")
        run.describe("metrics.csv", "one row per processed frame: seq, sim time, UGVs detected, "
                     "centre of mass, spread, latency, φ(s)")  # fmt: skip
        metrics = run.metrics(
            ["seq", "t_sim", "count", "all_in_view", "com_u_px", "com_v_px", "radius_px",
             "latency_ms", *FEATURE_NAMES]
        )  # fmt: skip
        run.at_end(finish, "summary")
        bar = run.closing(tqdm(total=args.frames, desc="watch", unit="frame", disable=None))
        _loop(args, sub, st, metrics, run, bar, ctrl_c)
        ctrl_c.check()  # outside every lock: the run folder ends as interrupted
        if st["processed"] == 0:
            refused = sub.stats.refused
            why = (f"{refused} refused as not signed with --signing-key {args.signing_key} (another "
                   "flight's key, or an unsigned source?)" if refused else
                   f"is a flight publishing? --connect {args.connect}")  # fmt: skip
            run.fail(
                f"no frame on skyherd/{args.vehicle}/camera/frame within {args.timeout:g} s ({why})"
            )
    if run.outcome == "failed":
        print(f"skyherd watch: {run.reason}")
        return 1
    return 0


def _loop(args, sub, st: dict, metrics, run, bar, ctrl_c: CtrlC) -> None:
    """Detect on frames until --frames are processed, --timeout passes without one, or Ctrl-C
    (`ctrl_c`, checked between frames; also at once, for one that came during start-up)."""
    from skyherd.runio import atomic_write_bytes

    shown = not args.no_show
    t_last = time.monotonic()
    while st["processed"] < args.frames and not ctrl_c.requested:
        fr = sub.wait(0.2)

        if fr is None:
            if time.monotonic() - t_last > args.timeout:
                break
            continue
        t_last = time.monotonic()
        det_ = st["detector"]
        if det_ is None or det_.cam.width_px != fr.image.shape[1]:
            det_ = st["detector"] = Detector(_camera_from(sub.info, fr.image.shape[:2]), args.ugvs)
        det = det_.detect(fr.image)
        phi = det_.features(det, -float(fr.pos_ned[2]))
        img = annotate(fr.image, det, scale=2)
        com = det.measure.com_px if det.measure.com_px is not None else (np.nan, np.nan)
        metrics.write({
            "seq": fr.seq, "t_sim": fr.t_sim, "count": det.count,
            "all_in_view": int(det.all_in_view), "com_u_px": float(com[0]),
            "com_v_px": float(com[1]), "radius_px": det.measure.radius_px,
            "latency_ms": 1e3 * fr.latency_s, **dict(zip(FEATURE_NAMES, phi.tolist())),
        })  # fmt: skip
        if st["processed"] % args.save_every == 0:
            ok, png = cv2.imencode(".png", cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
            if ok:
                atomic_write_bytes(run.path / "frames" / f"frame_{fr.seq:06d}.png", png.tobytes())
        st["strip"].append((fr.t_sim, img))
        shown = _try_show(img, shown)
        st["counts"].append(det.count)
        st["all_in"].append(det.all_in_view)
        st["processed"] += 1
        bar.update(1)


def _recorder(session, vehicle: str, path, live, key: bytes | None):
    """A ZenohRecorder into `path` and/or the live server (with `key`: authentic records only)."""
    from skyherd.record import ZenohRecorder

    return ZenohRecorder(session, vehicle, path, also=[live] if live is not None else [], key=key)
