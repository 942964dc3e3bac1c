"""The options of `skyherd fly` and `skyherd sim`, each defined once: the ones both commands take
(fly passes them on to its simulator), and the formation's and the orbit's, kept apart from their
missions so that `skyherd fly` (the ground-air default) imports neither mission's code to parse
its line."""

from __future__ import annotations

from skyherd.flight.clock import SPEEDUP_HELP
from skyherd.runio import ports
from skyherd.runio.constants import GCS_REMOTE_PORT, LOCKSTEP_LATENCY_S
from skyherd.runio.run import UsageError

AGENT_CHOICES = (1, 4, 9, 16)


def _shared(fly: bool) -> dict[str, dict]:
    """The options `skyherd sim` and `skyherd fly` share: flag → add_argument's keywords, the
    help as `fly` (True) or `sim` says it."""
    said = lambda sim, fly_: fly_ if fly else sim  # noqa: E731 - one help per command
    repeatable = "" if fly else " (repeatable)"
    return {
        "--airframe": dict(choices=["quadrotor", "fixedwing"], default="quadrotor", help=said(
            "the vehicle: the quadrotor (downward camera) or the JSBSim fixed-wing (its camera on a "
            "pan-tilt gimbal pointed where a client sets the ROI: DO_SET_ROI_LOCATION)",
            "quadrotor, or fixedwing (JSBSim; flies the ground-air task as an orbit)")),
        "--instance": dict(type=int, default=0, help=said(
            f"vehicle instance N in [0, {ports.MAX_INSTANCE}]: {ports.MAVLINK_PORTS_HELP}, "
            f"{ports.ZENOH_PORT_HELP} and system id 1+N",
            f"built-in vehicle instance N in [0, {ports.MAX_INSTANCE}]: its MAVLink ports "
            f"{ports.MAVLINK_PORTS_HELP} and its {ports.ZENOH_PORT_HELP}")),
        "--seed": dict(type=int, default=0, help=said(
            "seed of the vehicle, the UGV team and every random source", "simulation seed")),
        "--ugvs": dict(default="composite", metavar="SCENARIO", help=said(
            "UGV team: lateral, climb, descend, composite, groundsim:route|convoy|random|stopgo|"
            "speedoff|camouflage, flock (flees the UAV: groundsim/flock.py); none: the vehicle "
            "alone (no team, no camera, no Zenoh session)",
            "UGV team: lateral, climb, descend, composite (the training scenarios), "
            "groundsim:route|convoy|random|stopgo|speedoff|camouflage, or flock (--mission "
            "shepherd's default: a flock that flees the UAV, groundsim/flock.py)")),
        "--speedup": dict(type=float, default=None, metavar="S",
                          help=SPEEDUP_HELP + ("; --connect free-runs" if fly else "")),
        "--free-run": dict(action="store_true", help=said(
            "do not wait for the companion (measure its lag instead)",
            "the simulator does not wait for the companion (its lag is measured instead)")),
        "--latency": dict(type=float, default=LOCKSTEP_LATENCY_S, metavar="S",
                          help="lockstep: the companion's declared compute latency [s of simulation time]"),
        "--zenoh-port": dict(type=int, default=None, help=said("Zenoh listen port", "the simulator's Zenoh port")
                             + f" on {ports.LOOPBACK} (default: {ports.ZENOH_BASE}+N for --instance N)"),
        "--param": dict(action="append", default=[], metavar="NAME=VALUE", help=said("set a", "a")
                        + " parameter of the built-in autopilot at start (repeatable), e.g. COM_OF_LOSS_T=3"),
        "--signing-key": dict(default=None, metavar="FILE", help=said(
            "MAVLink 2 signing key file (32 bytes): sign every frame, reject unsigned ones",
            "MAVLink 2 signing key file (32 bytes) for the vehicle (every vehicle of a formation), "
            "the companion, the world's link and the Zenoh records' MACs (default with the built-in "
            "vehicle: a new key per run, <run>/signing.key)")),
        "--cut-link": dict(action="append", default=[], metavar="T:D",
                           help="cut the companion's MAVLink link both ways at simulation time T [s] "
                           f"for D [s]{repeatable}"),
        "--cut-camera": dict(action="append", default=[], metavar="T:D",
                             help=f"stop the camera's frames at T [s] for D [s]{repeatable}"),
        "--runs-dir": dict(default="runs", help=said("where the run folder goes", "where run folders go")),
    }  # fmt: skip


def add_shared(parser, *flags: str, fly: bool = False) -> None:
    """The shared options `flags`, in this order, as `skyherd fly` (`fly`) or `skyherd sim`."""
    shared = _shared(fly)
    for flag in flags:
        parser.add_argument(flag, **shared[flag])


PASSED_TO_SIM = ("param", "cut_link", "cut_camera", "wind", "gust", "noise", "fault")
"""The options `skyherd fly` hands its simulator as they were given, in this order."""


def passed_on(args, dests: tuple[str, ...] = PASSED_TO_SIM) -> list[str]:
    """The options `dests` as a child's argument list: a repeatable one once per item, one
    with a value when it has one."""
    out: list[str] = []
    for dest in dests:
        value = getattr(args, dest)
        for item in value if isinstance(value, list) else [value] if value else []:
            out += [f"--{dest.replace('_', '-')}", item]
    return out


def flight_signing(args):
    """How the flight is signed (flight.mavlink.signing.FlightSigning), from --signing-key,
    --no-signing, --connect and --setup-signing."""
    from skyherd.flight.mavlink.signing import FlightSigning

    return FlightSigning(args.signing_key, args.no_signing, args.connect is not None,
                         getattr(args, "setup_signing", False))  # fmt: skip


def check_signing(args) -> str | None:
    """The key file's absolute path (None: a per-run key, or unsigned); UsageError, one line."""
    try:
        return flight_signing(args).checked_key_file()
    except ValueError as e:
        raise UsageError(str(e)) from None


def signing_mode(args) -> str:
    return flight_signing(args).mode()


def per_run_key(args, run_dir):
    return flight_signing(args).per_run_key(run_dir)


def add_formation_arguments(group) -> None:
    """Options of the formation mission (added to `skyherd fly` in an argument group)."""
    group.add_argument("--agents", type=int, choices=AGENT_CHOICES, default=9,
                       help="K: vehicles and formation targets (1, 4, 9 or 16; default 9; 1 needs --policy-file); "
                       "the vehicles are instances N, N+1, ... with N = --instance, skipping 10 (PX4 layout: its "
                       f"companion port is the ground stations' {GCS_REMOTE_PORT})")  # fmt: skip
    group.add_argument(
        "--sql-seed",
        type=int,
        default=0,
        help="seed of the in-process SQL-SIE training (default 0)",
    )
    group.add_argument(
        "--cell-m", type=float, default=2.0, help="grid cell size on the field [m] (default 2)"
    )
    group.add_argument("--sims", type=int, default=0, metavar="G",
                       help="simulator processes the K vehicles are shared among (1..K; default 0: one per "
                       "CPU core, at most K): each steps its vehicles in turn, each vehicle in lockstep with "
                       "the companion, so the flight is the same for any G")  # fmt: skip
    group.add_argument("--policy-file", default=None,
                       help="a plan_K<K>.json from `skyherd train sql` (default: train SQL-SIE in-process, "
                       "10,000 episodes, a few seconds)")  # fmt: skip


def add_orbit_arguments(group) -> None:
    """The orbit's options (all prefixed --orbit-, so they sit beside the other missions')."""
    group.add_argument("--orbit-scenario", choices=["lateral", "composite"], default="lateral",
                       help="UGV team behaviour (policy.groundair.scenarios), default lateral")  # fmt: skip
    group.add_argument("--orbit-duration", type=float, default=None,
                       help="established orbit time before landing [s] (default 90)")  # fmt: skip
    group.add_argument(
        "--orbit-no-land", action="store_true", help="end in the orbit instead of landing"
    )
