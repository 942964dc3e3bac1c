"""`skyherd sim`: the world — one vehicle with its autopilot and MAVLink endpoints, the UGV team,
the downward camera on Zenoh — owning the one simulation clock, until interrupted.

With `--lockstep` (the default) the simulation holds at every camera frame for the companion's
decision (`skyherd companion` closes each tick), so a flight is the same at any speed-up and
any machine load; `--free-run` steps on the pacer alone, as a real autopilot would, and
measures how late the companion's setpoints act.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from skyherd.runio import RunFolder, args_dict
from skyherd.runio.constants import CAMERA_HZ
from skyherd.runio.process import parent_gone
from skyherd.scripts.cli import UsageError, check_with
from skyherd.scripts.fault_options import add_fault_arguments
from skyherd.scripts.fly_options import add_shared

PARENT = os.getppid()  # the process that started this one (`skyherd fly`, a shell)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_shared(parser, "--airframe", "--instance", "--seed", "--ugvs")
    parser.add_argument(
        "--home",
        default=None,
        metavar="LAT,LON,ALT",
        help="the vehicle's home [deg, deg, m AMSL] (default: the project's default home)",
    )
    parser.add_argument(
        "--ugv-start",
        default="offboard",
        metavar="WHEN",
        help="when the UGVs start to drive: 'offboard' (when the vehicle is handed to the companion: "
        "OFFBOARD for the built-in vehicle; beside --follow or --autopilot, the companion's first "
        "decision on skyherd/<vehicle>/decision) or a simulation time [s] (default offboard)",
    )
    add_shared(parser, "--speedup")
    parser.add_argument(
        "--camera-hz",
        type=float,
        default=CAMERA_HZ,
        help="camera frames per simulated second (the companion's tick) (default %(default)s)",
    )
    add_shared(parser, "--free-run", "--latency")
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after this much simulation time [s] (default: until interrupted)",
    )
    add_shared(parser, "--zenoh-port")
    parser.add_argument(
        "--zenoh-config",
        default=None,
        metavar="FILE",
        help="a Zenoh JSON5 configuration instead (e.g. a router for two hosts; docs/topology.md)",
    )
    parser.add_argument(
        "--bind", default="127.0.0.1", metavar="HOST", help="address the MAVLink sockets bind to"
    )
    parser.add_argument(
        "--remote",
        default="127.0.0.1",
        metavar="HOST",
        help="host the companion and the ground station listen on",
    )
    parser.add_argument(
        "--follow",
        default=None,
        metavar="ADDRESS",
        help="no built-in vehicle: build the world (UGVs, camera) around the outside vehicle at "
        "this MAVLink address (a second link of PX4 / ArduPilot), free-running on its clock",
    )
    parser.add_argument("--autopilot", choices=["builtin", "px4", "ardupilot"], default="builtin",
                        help="builtin: skyherd's autopilot (default); px4 / ardupilot: a real one flies on skyherd's "
                        "physics (PX4 none_iris on TCP 4560+N, ArduPilot --model JSON on UDP 9002+10N)")  # fmt: skip
    parser.add_argument(
        "--follow-system",
        type=int,
        default=0,
        metavar="ID",
        help="with --follow: the followed autopilot's MAVLink system id (0: the first autopilot heard)",
    )
    add_shared(parser, "--param")
    add_fault_arguments(parser)
    add_shared(parser, "--signing-key", "--cut-link", "--cut-camera")
    parser.add_argument(
        "--fleet",
        default=None,
        metavar="FILE",
        help="several built-in vehicles in this one process (with --ugvs none): a JSON list of "
        '{"name": "uav0", "instance": N, "seed": S, "home": [LAT, LON, ALT]}; each writes into '
        "<run folder>/<name>/, each in lockstep with its own companion (docs/formation.md)",
    )
    add_shared(parser, "--runs-dir")
    parser.add_argument(
        "--run-dir",
        default=None,
        help="write into this existing run folder (used by `skyherd fly`)",
    )


def check_args(argv: list[str]) -> str | None:
    """`skyherd sim`'s own parser and checks on `argv`, starting nothing (no socket, no Zenoh
    session, no file): None if it would start, else the one-line reason. `skyherd fly` calls
    it before it makes its run folder."""
    return check_with("skyherd sim", add_arguments, check, argv)


def check(args):
    """Every check of the arguments that needs nothing started (world.setup.SimSetup.checked;
    UsageError, one line); the instance's Zenoh port and the speed-up's default filled in."""
    from skyherd.world.setup import SimSetup

    try:
        setup = SimSetup.of(args).checked()
    except ValueError as e:  # world.build.WorldError, a --param refused
        raise UsageError(str(e)) from None
    args.zenoh_port, args.speedup = setup.zenoh_port, setup.speedup
    return setup


def run(args: argparse.Namespace) -> int:
    from skyherd.world.serve import serve

    setup = check(args)
    if args.run_dir is not None:
        run_dir = Path(args.run_dir)
        if not run_dir.is_dir():
            raise UsageError(f"--run-dir {run_dir} is not a folder")
    else:
        folder = RunFolder("sim", root=args.runs_dir)
        folder.write_config({"args": args_dict(args), "world": setup.world_params()[0]})
        run_dir = folder.path
    try:
        vehicles = [v.name for v in setup.read_fleet()] if setup.fleet else None
        rc = serve(setup, run_dir, say, PARENT)
    except ValueError as e:  # world.build.WorldError: a world that cannot start
        raise UsageError(str(e)) from None
    if rc == 0 and args.run_dir is not None and parent_gone(PARENT):
        # under `skyherd fly` whose process died (kill -9): the simulator, the last child to
        # end, says how the flight ended in summary.md
        from skyherd.report.ending import parent_died

        parent_died(run_dir, vehicles)
    return rc


def say(text: str) -> None:
    """A line on stderr (sim.log in a run folder), never raising: a full disk or a read-only
    folder must not stop the vehicle."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass
