"""`skyherd teleop`: a demonstration of a GroundAir scenario flown from the keyboard, or from
MAVLink MANUAL_CONTROL (`--mavlink ADDRESS`, `--continuous`): hil.teleop. The run folder gets
config.json, summary.md and `<scenario>.npz` (or --out), in the skyherd-demo format
(policy.demos), ready for `skyherd train irl|ab|abs-dl --demos FOLDER`."""

from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

from skyherd.hil.teleop import TeleopParams, record_keyboard, record_stick
from skyherd.report.teleop import save_demo
from skyherd.runio import RunFolder, UsageError
from skyherd.scripts.options import add_options, opt, values


@dataclass(frozen=True)
class TeleopOptions:
    """`skyherd teleop`'s options beside hil.teleop.TeleopParams' (scripts.options)."""

    out: Path | None = None
    """output .npz (default: <scenario>.npz in the run folder, ready for `skyherd train irl|ab
    --demos FOLDER`)"""
    runs_dir: Path = Path("runs")  # where run folders go
    mavlink: str | None = opt(None, metavar="ADDRESS")
    """take MANUAL_CONTROL from a joystick/ground station at ADDRESS instead of keys"""
    continuous: bool = False
    """with --mavlink: record the stick as a continuous velocity (ABS-DL's limits,
    skyherd-demo/2) instead of the seven discrete actions"""
    no_view: bool = False  # do not draw the text view


def add_arguments(parser: argparse.ArgumentParser) -> None:
    scenarios = ("lateral", "climb", "descend", "composite")
    add_options(parser, TeleopParams, skip=("view",), scenario=dict(choices=scenarios))
    add_options(parser, TeleopOptions)


def run(args: argparse.Namespace) -> int:
    if args.episodes < 1 or args.step_s < 0 or args.episode_s <= 0:
        raise UsageError("need --episodes >= 1, --step-s >= 0 and --episode-s > 0")
    if args.continuous and not args.mavlink:
        raise UsageError("--continuous needs --mavlink ADDRESS (keys have no proportional axis)")
    p = values(TeleopParams, args, view=not args.no_view)
    if args.mavlink:
        return _run_mavlink(args, p)
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        raise UsageError("teleop needs a terminal on stdin (run it in a terminal, not a pipe)")
    with RunFolder.open("teleop", args, root=args.runs_dir) as run:
        out = _out_path(args, run)
        return save_demo(run, record_keyboard(p, fd), out, args.scenario, "keyboard")


def _run_mavlink(args: argparse.Namespace, p: TeleopParams) -> int:
    """Record a demonstration from MAVLink MANUAL_CONTROL messages."""
    from skyherd.hil.link import MavlinkLink
    from skyherd.runio import AddressError, mavlink_address

    try:
        address = mavlink_address(args.mavlink)
    except AddressError as e:
        raise UsageError(f"--mavlink {e}") from e
    try:
        link = MavlinkLink.open(address)
    except Exception as e:
        raise UsageError(f"cannot open {args.mavlink}: {e}") from e
    with RunFolder.open("teleop", args, root=args.runs_dir) as run:
        run.closing(link)
        out = _out_path(args, run)
        try:
            demo = record_stick(p, link, args.mavlink, args.continuous)
        finally:
            link.close()
        mode = "continuous" if args.continuous else "discrete"
        return save_demo(run, demo, out, args.scenario, f"MAVLink MANUAL_CONTROL, {mode}")


def _out_path(args: argparse.Namespace, run) -> Path:
    out = args.out or run.file(f"{args.scenario}.npz")
    out.parent.mkdir(parents=True, exist_ok=True)
    return out
