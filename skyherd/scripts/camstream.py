"""`skyherd camstream`: a frame source on its own (perception/camstream.py): UGVs on a route
and a UAV hovering over them, its camera's frames and the UGVs' states on Zenoh, so that
`skyherd watch`, the Zenoh tests and the benchmark have a real second process to talk to."""

from __future__ import annotations

import argparse
import re
import sys

from skyherd.perception.camstream import CamstreamParams
from skyherd.runio import ports
from skyherd.scripts.cli import UsageError, usage
from skyherd.scripts.options import add_options, values


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_options(
        parser,
        CamstreamParams,
        rate_hz=dict(flag="--rate"),
        sim_dt_s=dict(flag="--sim-dt"),
        encoding=dict(choices=("raw", "jpeg")),
    )


def run(args: argparse.Namespace) -> int:
    from skyherd.perception.camstream import stream

    usage(ports.check_port, args.port, "--port")
    if not re.fullmatch(r"\d+x\d+", args.size.lower()):
        raise UsageError(f"--size {args.size}: give WxH in pixels, e.g. 320x240")
    sent = stream(values(CamstreamParams, args))
    print(f"camstream: sent {sent} frames", file=sys.stderr)
    return 0
