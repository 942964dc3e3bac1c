"""`skyherd camstream`: a frame source on its own (perception/camstream.py): UGVs on a route
and a UAV hovering over them, its camera's frames and the UGVs' states on Zenoh, so that
`skyherd watch`, the Zenoh tests and the benchmark have a real second process to talk to."""

from __future__ import annotations

import argparse
import re
import sys

from skyherd.perception.camstream import CamstreamParams
from skyherd.runio import ports
from skyherd.scripts.cli import UsageError

D = CamstreamParams()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--vehicle", default=D.vehicle,
                        help="vehicle name in the key (default: %(default)s)")  # fmt: skip
    parser.add_argument("--port", type=int, default=D.port,
                        help=f"listen on tcp/{ports.LOOPBACK}:PORT (default: %(default)s)")  # fmt: skip
    parser.add_argument("--config", default=None, help="Zenoh JSON5 config file (replaces --port)")
    parser.add_argument("--frames", type=int, default=D.frames,
                        help="frames to send, 0 = until interrupted (default: %(default)s)")  # fmt: skip
    parser.add_argument("--rate", type=float, default=D.rate_hz,
                        help="frames per second, 0 = as fast as possible (default: %(default)s)")  # fmt: skip
    parser.add_argument("--sim-dt", type=float, default=D.sim_dt_s,
                        help="simulation time per frame [s] (default: %(default)s)")  # fmt: skip
    parser.add_argument("--size", default=D.size, help="image WxH (default: %(default)s)")
    parser.add_argument("--encoding", choices=("raw", "jpeg"), default=D.encoding,
                        help="(default: %(default)s)")  # fmt: skip
    parser.add_argument("--behaviour", default=D.behaviour,
                        help="the UGVs' groundsim behaviour (default: %(default)s)")  # fmt: skip
    parser.add_argument("--wait-s", type=float, default=D.wait_s,
                        help="wait up to this long for a subscriber [s] (default: %(default)s)")  # fmt: skip
    parser.add_argument("--static", action="store_true", help="send one pre-rendered frame (bench)")
    parser.add_argument("--seed", type=int, default=D.seed, help="(default: %(default)s)")


def run(args: argparse.Namespace) -> int:
    from skyherd.perception.camstream import stream

    try:
        ports.check_port(args.port, "--port")
    except ValueError as e:
        raise UsageError(str(e)) from None
    if not re.fullmatch(r"\d+x\d+", args.size.lower()):
        raise UsageError(f"--size {args.size}: give WxH in pixels, e.g. 320x240")
    p = CamstreamParams(args.vehicle, args.port, args.config, args.frames, args.rate, args.sim_dt,
                        args.size, args.encoding, args.behaviour, args.wait_s, args.static,
                        args.seed)  # fmt: skip
    sent = stream(p)
    print(f"camstream: sent {sent} frames", file=sys.stderr)
    return 0
