"""The options of `skyherd fly` and `skyherd sim`, each defined once: the ones both commands take
(fly passes them on to its simulator), and the formation's and the orbit's, kept apart from their
missions so that `skyherd fly` (the ground-air default) imports neither mission's code to parse
its line."""

from __future__ import annotations

import importlib
from dataclasses import dataclass

from skyherd.flight.clock import SPEEDUP_HELP
from skyherd.runio import ports
from skyherd.runio.constants import GCS_REMOTE_PORT
from skyherd.scripts.cli import COMMANDS, CheckParser, UsageError
from skyherd.scripts.options import opt

AGENT_CHOICES = (1, 4, 9, 16)

WORLD = {
    "airframe": dict(choices=["quadrotor", "fixedwing"]),
    "instance": dict(
        help=f"vehicle instance N in [0, {ports.MAX_INSTANCE}]: "
        f"{ports.MAVLINK_PORTS_HELP}, {ports.ZENOH_PORT_HELP} and system id 1+N"
    ),
    "ugvs": dict(metavar="SCENARIO"),
    "home": dict(metavar="LAT,LON,ALT"),
    "ugv_start": dict(metavar="WHEN"),
    "speedup": dict(metavar="S", help=SPEEDUP_HELP),
    "latency": dict(metavar="S"),
    "duration": dict(metavar="S"),
    "zenoh_port": dict(
        help=f"Zenoh listen port on {ports.LOOPBACK} (default: {ports.ZENOH_BASE}+N for "
        "--instance N)"
    ),
    "zenoh_config": dict(metavar="FILE"),
    "bind": dict(metavar="HOST"),
    "remote": dict(metavar="HOST"),
    "follow": dict(metavar="ADDRESS"),
    "autopilot": dict(choices=["builtin", "px4", "ardupilot"]),
    "follow_system": dict(metavar="ID"),
    "param": dict(action="append", metavar="NAME=VALUE"),
    "signing_key": dict(metavar="FILE"),
    "cut_link": dict(action="append", metavar="T:D"),
    "cut_camera": dict(action="append", metavar="T:D"),
    "fleet": dict(metavar="FILE"),
}
"""How `skyherd sim` and `skyherd fly` show world.setup.SimSetup's fields (scripts.options)."""

FLY_WORLD = {
    **WORLD,
    "airframe": dict(
        WORLD["airframe"],
        help="quadrotor, or fixedwing (JSBSim; flies the ground-air task as an orbit)",
    ),
    "ugvs": dict(
        metavar="SCENARIO",
        help="UGV team: lateral, climb, descend, composite (the training scenarios), groundsim:"
        "route|convoy|random|stopgo|speedoff|camouflage, or flock (--mission shepherd's "
        "default: a flock that flees the UAV, groundsim/flock.py)",
    ),
    "speedup": dict(metavar="S", help=SPEEDUP_HELP + "; --connect free-runs"),
    "signing_key": dict(
        metavar="FILE",
        help="MAVLink 2 signing key file (32 bytes) for the vehicle (every vehicle of a "
        "formation), the companion, the world's link and the Zenoh records' MACs (default with "
        "the built-in vehicle: a new key per run, <run>/signing.key)",
    ),
}
"""... and where `skyherd fly` says it otherwise."""


def child_argv(command: str, **values) -> list[str]:
    """`values` (attribute → value) as `skyherd <command>`'s argument list, each with that
    command's own flag: a flag alone for True, once per item for a list, nothing for None,
    False or an empty list."""
    parser = CheckParser()
    importlib.import_module(COMMANDS[command][0]).add_arguments(parser)
    flags = {a.dest: a.option_strings[0] for a in parser._actions if a.option_strings}
    out: list[str] = []
    for dest, value in values.items():
        for item in value if isinstance(value, list | tuple) else [value]:
            if item is True:
                out.append(flags[dest])
            elif item is not None and item is not False:
                out += [flags[dest], str(item)]
    return out


def check_child(command: str, argv: list[str]) -> None:
    """`skyherd <command>`'s own parser and checks on the arguments `skyherd fly` passes it
    (scripts.sim and scripts.companion `check_args`), starting nothing and before fly writes
    anything: UsageError with the child's one-line reason."""
    why = importlib.import_module(COMMANDS[command][0]).check_args(argv)
    if why:
        raise UsageError(why)


def flight_signing(args):
    """How the flight is signed (flight.mavlink.keys.FlightSigning), from --signing-key,
    --no-signing, --connect and --setup-signing."""
    from skyherd.flight.mavlink.keys import FlightSigning

    return FlightSigning(args.signing_key, args.no_signing, args.connect is not None,
                         getattr(args, "setup_signing", False))  # fmt: skip


@dataclass(frozen=True)
class FormationOptions:
    """The formation mission's options (`skyherd fly`'s group; scripts.options)."""

    agents: int = opt(
        9,
        choices=AGENT_CHOICES,
        help="K: vehicles and formation targets (1, 4, 9 or 16; default 9; 1 needs "
        "--policy-file); the vehicles are instances N, N+1, ... with N = --instance, skipping 10 "
        f"(PX4 layout: its companion port is the ground stations' {GCS_REMOTE_PORT})",
    )
    sql_seed: int = 0  # seed of the in-process SQL-SIE training (default 0)
    cell_m: float = 2.0  # grid cell size on the field [m] (default 2)
    sims: int = opt(0, metavar="G")
    """simulator processes the K vehicles are shared among (1..K; default 0: one per CPU core,
    at most K): each steps its vehicles in turn, each vehicle in lockstep with the companion,
    so the flight is the same for any G"""
    policy_file: str | None = None
    """a plan_K<K>.json from `skyherd train sql` (default: train SQL-SIE in-process, 10,000
    episodes, a few seconds)"""


@dataclass(frozen=True)
class OrbitOptions:
    """The orbit's options (all prefixed --orbit-, so they sit beside the other missions')."""

    orbit_scenario: str = opt("lateral", choices=["lateral", "composite"])
    """UGV team behaviour (policy.groundair.scenarios), default lateral"""
    orbit_duration: float | None = None  # established orbit time before landing [s] (default 90)
    orbit_no_land: bool = False  # end in the orbit instead of landing
