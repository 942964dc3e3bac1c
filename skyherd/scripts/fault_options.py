"""The fault flags of `skyherd sitl`, `skyherd sim` and `skyherd fly` (--wind, --gust, --noise,
--fault): one definition, parsed by flight.faults.parse_fault_args (docs/quadrotor.md, faults)."""

from __future__ import annotations

from skyherd.flight.faults import FaultPlan, parse_fault_args


def add_fault_arguments(parser) -> None:
    """The fault flags on an argparse parser or argument group."""
    parser.add_argument("--wind", default=None, metavar="SPEED,FROM[,DOWN]",
                        help="mean wind [m/s] from FROM degrees (270 = from the west); default calm")  # fmt: skip
    parser.add_argument("--gust", default=None, metavar="STD[,TAU]",
                        help="gust std [m/s] and correlation time [s, default 2]; default none")  # fmt: skip
    parser.add_argument("--noise", default=None, metavar="POS[,VEL]",
                        help="estimate noise std: position [m], velocity [m/s]; default none")  # fmt: skip
    parser.add_argument("--fault", action="append", default=[], metavar="KIND@T[:ARGS][:DUR]",
                        help="timed fault, repeatable: gps_glitch@30:20,0,0:5, gps_drift@30:0.5,0,0:20, "
                        "gps_loss@30:10, baro@30:5:20, wind@40:16,90:10, battery@60:0.06, "
                        "drain@10:300:60, disarm@25, rtl@25.02:0.05")  # fmt: skip


def plan_from_args(args, seed: int = 0) -> FaultPlan:
    """FaultPlan from an argparse namespace filled by `add_fault_arguments`."""
    return parse_fault_args(args.wind, args.gust, args.noise, args.fault, seed=seed)
