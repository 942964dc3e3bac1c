"""`skyherd teleop`: a demonstration of a GroundAir scenario flown from the keyboard, or from
MAVLink MANUAL_CONTROL (`--mavlink ADDRESS`, `--continuous`): hil.teleop. The run folder gets
config.json, summary.md and `<scenario>.npz` (or --out), in the skyherd-demo format
(policy.demos), ready for `skyherd train irl|ab|abs-dl --demos FOLDER`."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from skyherd.hil.teleop import TeleopParams, record_keyboard, record_stick
from skyherd.report.teleop import save_demo
from skyherd.runio import RunFolder, UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        default="lateral",
        choices=("lateral", "climb", "descend", "composite"),
        help="what to demonstrate",
    )
    parser.add_argument("--episodes", type=int, default=1, help="episodes to record")
    parser.add_argument("--seed", type=int, default=0, help="environment seed of the first episode")
    parser.add_argument(
        "--step-s",
        type=float,
        default=0.5,
        help="wall seconds per step; 0 = wait for a key each step",
    )
    parser.add_argument(
        "--episode-s", type=float, default=60.0, help="episode length [s] (sim time)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output .npz (default: <scenario>.npz in the run folder, ready for "
        "`skyherd train irl|ab --demos FOLDER`)",
    )
    parser.add_argument(
        "--runs-dir", dest="runs_dir", type=Path, default=Path("runs"),
        help="where run folders go",
    )  # fmt: skip
    parser.add_argument(
        "--mavlink",
        default=None,
        metavar="ADDRESS",
        help="take MANUAL_CONTROL from a joystick/ground station at ADDRESS instead of keys",
    )
    parser.add_argument(
        "--continuous",
        action="store_true",
        help="with --mavlink: record the stick as a continuous velocity (ABS-DL's limits, "
        "skyherd-demo/2) instead of the seven discrete actions",
    )
    parser.add_argument("--no-view", action="store_true", help="do not draw the text view")


def run(args: argparse.Namespace) -> int:
    if args.episodes < 1 or args.step_s < 0 or args.episode_s <= 0:
        raise UsageError("need --episodes >= 1, --step-s >= 0 and --episode-s > 0")
    if args.continuous and not args.mavlink:
        raise UsageError("--continuous needs --mavlink ADDRESS (keys have no proportional axis)")
    p = TeleopParams(
        args.scenario, args.episodes, args.seed, args.step_s, args.episode_s, not args.no_view
    )
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
