"""The fault flags of `skyherd sitl`, `skyherd sim` and `skyherd fly` (--wind, --gust, --noise,
--fault): one definition, world.setup.SimSetup's fields, parsed by flight.faults.parse_fault_args
(docs/quadrotor.md, faults)."""

from __future__ import annotations

from skyherd.flight.faults import FaultPlan, parse_fault_args
from skyherd.scripts.options import add_options
from skyherd.world.setup import SimSetup

FAULTS = ("wind", "gust", "noise", "fault")


def add_fault_arguments(parser) -> None:
    """The fault flags on an argparse parser or argument group."""
    add_options(
        parser,
        SimSetup,
        only=FAULTS,
        wind=dict(metavar="SPEED,FROM[,DOWN]"),
        gust=dict(metavar="STD[,TAU]"),
        noise=dict(metavar="POS[,VEL]"),
        fault=dict(action="append", metavar="KIND@T[:ARGS][:DUR]"),
    )


def plan_from_args(args, seed: int = 0) -> FaultPlan:
    """FaultPlan from an argparse namespace filled by `add_fault_arguments`."""
    return parse_fault_args(args.wind, args.gust, args.noise, args.fault, seed=seed)
