"""`skyherd sim`: the world — one vehicle with its autopilot and MAVLink endpoints, the UGV team,
the downward camera on Zenoh — owning the one simulation clock, until interrupted.

With `--lockstep` (the default) the simulation holds at every camera frame for the companion's
decision (`skyherd companion` closes each tick), so a flight is the same at any speed-up and
any machine load; `--free-run` steps on the pacer alone, as a real autopilot would, and
measures how late the companion's setpoints act.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from dataclasses import dataclass

from skyherd.runio import args_dict
from skyherd.runio.pin import PIN_CHOICES, PIN_HELP
from skyherd.runio.process import parent_gone, say
from skyherd.runio.run import given_or_new_run_folder
from skyherd.scripts.cli import UsageError, check_with, usage
from skyherd.scripts.fault_options import FAULTS, add_fault_arguments
from skyherd.scripts.fly_options import WORLD
from skyherd.scripts.options import add_options
from skyherd.world.setup import SimSetup

PARENT = os.getppid()  # the process that started this one (`skyherd fly`, a shell)


@dataclass(frozen=True)
class SimFolder:
    """Where `skyherd sim` writes (scripts.options)."""

    runs_dir: str = "runs"  # where the run folder goes
    run_dir: str | None = None  # write into this existing run folder (used by `skyherd fly`)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    world = [f.name for f in dataclasses.fields(SimSetup)]
    pin = dict(pin_cpu=dict(metavar=PIN_CHOICES, help=PIN_HELP + "; with --autopilot ardupilot"))
    add_options(parser, SimSetup, only=tuple(world[: world.index("wind")]), **WORLD, **pin)
    add_fault_arguments(parser)
    add_options(
        parser,
        (SimSetup, SimFolder),
        skip=FAULTS,
        only=(*world[world.index("wind") :], "runs_dir", "run_dir"),
        **WORLD,
    )


def check_args(argv: list[str]) -> str | None:
    """`skyherd sim`'s own parser and checks on `argv`, starting nothing (no socket, no Zenoh
    session, no file): None if it would start, else the one-line reason. `skyherd fly` calls
    it before it makes its run folder."""
    return check_with("skyherd sim", add_arguments, check, argv)


def check(args):
    """Every check of the arguments that needs nothing started (world.setup.SimSetup.checked;
    UsageError, one line); the instance's Zenoh port and the speed-up's default filled in."""
    setup = usage(SimSetup.of(args).checked)  # world.build.WorldError, a --param refused
    args.zenoh_port, args.speedup = setup.zenoh_port, setup.speedup
    return setup


def run(args: argparse.Namespace) -> int:
    from skyherd.world.serve import serve

    setup = check(args)
    run_dir, folder = given_or_new_run_folder("sim", args.run_dir, args.runs_dir)
    if folder is not None:  # on its own, not under `skyherd fly`
        folder.write_config({"args": args_dict(args), "world": setup.world_params()[0]})
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
