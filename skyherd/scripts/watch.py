"""`skyherd watch`: a vehicle's camera frames from Zenoh (loopback by default), the UGVs
detected on each (perception.watch), annotated PNGs, metrics.csv, strip.png and summary.md
(report.watch) in `runs/<time>-watch/`, flight.mcap (record). Exit codes: 0 frames were
processed; 1 no frame arrived before --timeout; 2 bad usage."""

from __future__ import annotations

import argparse
import signal
from dataclasses import dataclass

from skyherd.perception.features import FeatureParams
from skyherd.perception.transport import ZenohParams, open_viewer
from skyherd.perception.watch import WatchParams
from skyherd.runio import RunFolder, UsageError, ports
from skyherd.runio.address import zenoh_config_file
from skyherd.runio.signals import CtrlC
from skyherd.scripts.cli import usage
from skyherd.scripts.options import add_options, opt, values


@dataclass(frozen=True)
class WatchOptions:
    """`skyherd watch`'s options beside perception.watch.WatchParams' (scripts.options)."""

    vehicle: str = "uav0"  # vehicle name in the key
    connect: str | None = opt(
        None,
        metavar="ADDRESS",
        help="the frame source, in the address syntax of every command (tcp:HOST:PORT; Zenoh's "
        f"tcp/HOST:PORT is accepted too) (default: {ports.ZENOH_ADDRESS_HELP} for --instance N)",
    )
    instance: int = opt(
        0,
        metavar="N",
        help=f"watch the flight of vehicle instance N in [0, {ports.MAX_INSTANCE}] (`skyherd "
        f"fly/sim --instance N`): its simulator's {ports.ZENOH_PORT_HELP} on {ports.LOOPBACK}",
    )
    zenoh_config: str | None = None  # Zenoh JSON5 config file (replaces --connect)
    signing_key: str | None = opt(None, metavar="FILE")
    """the flight's key file (32 bytes: `skyherd fly --signing-key FILE`, or the per-run
    <run>/signing.key): take only authentic frames and records, refuse (count) plain or forged
    ones (default: none, frames are shown unchecked)"""
    runs_dir: str = opt("runs", aliases=("--out",))  # where run folders go; --out is the older name
    strip: int = 8  # frames in strip.png
    no_show: bool = False  # never open a window
    mcap: bool = True
    """record the flight seen on Zenoh (frames, poses, UGVs, decisions, safety events, clock) as
    flight.mcap in the run folder, for Foxglove / PlotJuggler"""
    foxglove: int | None = opt(None, metavar="PORT")
    """also serve the flight live to Foxglove at ws://127.0.0.1:PORT"""


ORDER = ("vehicle", "connect", "instance", "zenoh_config", "signing_key", "frames", "runs_dir")
ORDER += ("ugvs", "timeout_s", "save_every", "strip", "no_show", "mcap", "foxglove")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(
        parser,
        (WatchOptions, WatchParams),
        only=ORDER,
        timeout_s=dict(flag="--timeout", dest="timeout"),
    )


def _check(args: argparse.Namespace) -> None:
    usage(ports.check_instance, args.instance)
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
    if args.zenoh_config:
        usage(zenoh_config_file, args.zenoh_config)


def run(args: argparse.Namespace) -> int:
    from skyherd.flight.mavlink.signing import key_option

    _check(args)
    key = usage(key_option, args.signing_key) if args.signing_key else None  # authentic frames
    ctrl_c = CtrlC()
    prev = signal.signal(signal.SIGINT, ctrl_c)
    try:
        zp, session = usage(open_viewer, args.connect, args.zenoh_config)
        try:
            ctrl_c.check()  # during the session's opening: no run folder
            return _watch(args, zp, session, ctrl_c, key)
        finally:
            # on every ending, however early (closing twice is harmless): its subscribers'
            # callback threads are not daemons, and the exit waits for them
            session.close()
    finally:
        signal.signal(signal.SIGINT, prev)


def _watch(args, zp: ZenohParams, session, ctrl_c: CtrlC, key: bytes | None) -> int:
    from tqdm import tqdm

    from skyherd.record import LiveServer
    from skyherd.record.watch import FlightWatch
    from skyherd.report.watch import finish_watch, no_frame

    w, live = FlightWatch(session, args.vehicle, key), None

    def finish() -> None:
        """Summary, strip.png: from what was received, on every ending (Ctrl-C too)."""
        w.close()
        finish_watch(run, w, args.strip, args.signing_key if key is not None else None)

    if args.foxglove is not None:
        try:
            live = LiveServer(args.foxglove)
        except OSError as e:
            session.close()
            raise UsageError(f"--foxglove {args.foxglove}: {e}") from e
        print(f"Foxglove: open ws://127.0.0.1:{live.port}")
    with RunFolder.open("watch", args, root=args.runs_dir) as run:
        run.config(zenoh=zp, feature_params=FeatureParams())
        w.record(run, args.mcap, live)
        run.at_end(finish, "summary")
        bar = run.closing(tqdm(total=args.frames, desc="watch", unit="frame", disable=None))
        p = values(WatchParams, args, timeout_s=args.timeout, show=not args.no_show)
        seen = w.watch(run, p, lambda: ctrl_c.requested, bar.update)
        ctrl_c.check()  # outside every lock: the run folder ends as interrupted
        if seen.processed == 0:
            refused = w.sub.stats.refused
            run.fail(no_frame(args.vehicle, args.timeout, refused, args.signing_key, args.connect))
    if run.outcome == "failed":
        print(f"skyherd watch: {run.reason}")
        return 1
    return 0
