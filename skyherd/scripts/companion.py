"""`skyherd companion --connect ADDRESS`: the onboard computer.

MAVLink client of the autopilot (component 191); camera frames from Zenoh; detector → φ(s) →
pilot (learned policy, PID follower, or the square's waypoints) → safety net → setpoints. It
owns no physics and no world. Against `skyherd sim` it ticks in lockstep on the vehicle's
marks; `--free-run` ticks on the autopilot's own clock (a real autopilot). Its options and
checks, and its run folder; the flight itself is mission.runner's.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from skyherd.mission.build import MissionChoice, mission_choice
from skyherd.runio import JsonlWriter, RunFolder, args_dict, ports
from skyherd.runio.run import given_or_new_run_folder
from skyherd.scripts.cli import UsageError, check_with, usage
from skyherd.scripts.options import add_options, opt


def pilot_choice(value: str) -> str:
    """--pilot: policy, pid, or drill:NAME (a named drill of safety.drills; - for a space)."""
    if value in ("policy", "pid") or value.startswith("drill:"):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: use policy, pid or drill:NAME")


@dataclass(frozen=True)
class LinkOptions:
    """`skyherd companion`'s options on its own, not under `skyherd fly` (scripts.options)."""

    connect: str | None = opt(
        None,
        metavar="ADDRESS",
        help="the autopilot's MAVLink address (pymavlink form; default "
        f"{ports.COMPANION_ADDRESS_HELP})",
    )
    instance: int = opt(
        0,
        help=f"vehicle instance N in [0, {ports.MAX_INSTANCE}] (system id 1+N, default "
        f"addresses: MAVLink {ports.COMPANION_ADDRESS_HELP}, Zenoh {ports.ZENOH_ADDRESS_HELP})",
    )
    free_run: bool = False
    """tick on the autopilot's clock instead of the simulator's marks (a real autopilot)"""
    zenoh_connect: str | None = opt(
        None,
        metavar="ADDRESS",
        help="where the camera frames are published (tcp:HOST:PORT; default: "
        f"{ports.ZENOH_ADDRESS_HELP} for --instance N)",
    )
    zenoh_config: str | None = opt(None, metavar="FILE")  # a Zenoh JSON5 configuration instead
    signing_key: str | None = opt(None, metavar="FILE")
    """MAVLink 2 signing key file (32 bytes) shared with the autopilot"""
    plan: str | None = opt(None, metavar="FILE")
    """--mission formation: the lock-step grid plan (plan.json / plan_K<K>.json); vehicle k is
    instance N+k, its home on its start cell"""
    cell_m: float = 2.0  # --mission formation: grid cell size [m]
    runs_dir: str = "runs"  # where the run folder goes
    run_dir: str | None = None  # write into this existing run folder (used by `skyherd fly`)
    wait_go: bool = False
    """set up, then wait for a line on standard input before the first message to the vehicle
    (its clock starts on it): how `skyherd fly` starts the flight once its recorder listens"""


@dataclass(frozen=True)
class FlightOptions:
    """The companion's options under `skyherd fly` too that are not mission.build.MissionChoice
    fields (scripts.options)."""

    no_camera: bool = False  # fly without camera frames (square, or no simulator)
    setup_signing: bool = False
    """an outside autopilot: first send it the --signing-key (SETUP_SIGNING) until it answers
    signed, then fly signed. ArduPilot accepts unsigned messages on SERIAL0 (TCP 5760+10N in
    SITL) whatever the key: connect to SERIAL1/2 for a protected link (docs/mavlink.md)"""


LINK = ("connect", "instance", "free_run", "zenoh_connect", "zenoh_config", "signing_key")
LINK += ("orbit_team", "orbit_seed", "orbit_no_land", "plan", "cell_m", "runs_dir", "run_dir")
LINK += ("wait_go",)  # standalone: LinkOptions' fields and MissionChoice's orbit ones
FLIGHT = ("mission", "shepherd_selector", "pilot", "lost_ugv_search", "policy", "envelope")
FLIGHT += ("altitude_m", "duration_s", "side_m", "no_camera", "setup_signing")
FLIGHT += ("configure_autopilot",)  # under `skyherd fly` too
SHOWN = {
    "orbit_team": dict(metavar="SCENARIO"),
    "shepherd_selector": dict(choices=["learned", "strombom"]),
    "pilot": dict(type=pilot_choice),
    "policy": dict(metavar="FILE"),
    "envelope": dict(metavar="FILE"),
    "altitude_m": dict(flag="--altitude", dest="altitude", metavar="M"),
    "duration_s": dict(flag="--duration", dest="duration", metavar="S"),
    "side_m": dict(flag="--side", dest="side", metavar="M"),
}  # how the options show MissionChoice's fields


MISSIONS = {
    "groundair": "groundair: keep the UGVs in view behind the safety net",
    "square": "square: fly a square",
    "formation": "formation: K vehicles fly the SQL-SIE plan to their targets",
    "orbit": "orbit: a fixed-wing orbits the team, camera on a pointed gimbal",
    "shepherd": "shepherd: herd the UGV flock (--ugvs flock) into the goal region "
    "(docs/shepherding.md)",
}  # --mission: each one's help


def add_arguments(parser, standalone: bool = True, missions: tuple[str, ...] = (*MISSIONS,)):
    if standalone:
        add_options(parser, (LinkOptions, MissionChoice), only=LINK, **SHOWN)
    said = "; ".join(MISSIONS[m] for m in missions)
    mission = dict(choices=list(missions), help=said)
    add_options(parser, (MissionChoice, FlightOptions), only=FLIGHT, **SHOWN, mission=mission)


def check_args(argv: list[str]) -> str | None:
    """`skyherd companion`'s own parser and checks on `argv`, starting nothing (no link, no
    Zenoh session, no file): None if it would start, else the one-line reason. `skyherd fly`
    calls it before it makes its run folder."""
    return check_with("skyherd companion", add_arguments, check, argv)


def check(args) -> str:
    """Every check of the arguments that needs nothing started (UsageError, one line); fills
    the instance's default addresses in. Returns the autopilot's MAVLink address."""
    from skyherd.flight.mavlink.keys import key_option
    from skyherd.hil.addresses import link_address
    from skyherd.runio.address import zenoh_config_file, zenoh_endpoint

    usage(ports.check_instance, args.instance)
    address = args.connect or ports.companion_address(args.instance)
    usage(link_address, address)
    if args.zenoh_connect is None:
        args.zenoh_connect = ports.zenoh_address(args.instance)
    try:
        zenoh_endpoint(args.zenoh_connect)
    except ValueError as e:
        raise UsageError(f"--zenoh-connect {e}") from None
    usage(mission_choice(args).checked)
    if args.mission == "formation" and args.plan is None:
        raise UsageError(
            "--mission formation needs --plan FILE (a plan_K<K>.json from `skyherd train sql`)"
        )
    if getattr(args, "setup_signing", False) and not (args.signing_key and args.free_run):
        raise UsageError("--setup-signing gives an outside autopilot your key: it needs "
                         "--signing-key FILE and --free-run")  # fmt: skip
    if args.mission == "shepherd" and args.no_camera:
        raise UsageError(
            "--mission shepherd reads the flock on the simulator's Zenoh session: drop --no-camera"
        )
    if args.signing_key:
        usage(key_option, args.signing_key)
    if args.zenoh_config is not None:
        usage(zenoh_config_file, args.zenoh_config)
    return address


def run(args: argparse.Namespace) -> int:
    from skyherd.mission.connect import open_camera, open_link, say
    from skyherd.mission.runner import fly_vehicle

    address = check(args)
    run_dir, folder = given_or_new_run_folder("companion", args.run_dir, args.runs_dir)
    if args.mission == "formation":
        return _run_formation(args, run_dir, folder)
    from skyherd.mission.build import build_mission
    from skyherd.runio.address import zenoh_endpoint

    mission, plan = _built(folder, build_mission, mission_choice(args), run_dir, say)
    if folder is not None:
        folder.write_config({"args": args_dict(args), "plan": plan, "address": address})
    session = frames = None
    if args.mission in ("groundair", "shepherd", "orbit") and not args.no_camera:
        session, frames = open_camera(mission, run_dir, zenoh_endpoint(args.zenoh_connect),
                                      args.zenoh_config, args.signing_key,
                                      flock=args.mission == "shepherd")  # fmt: skip
    mission.authority.log = JsonlWriter(run_dir / "modes.jsonl")  # every (mode, armed) change
    link = open_link(address, args.instance, run_dir / "telemetry.tlog", args.signing_key,
                     args.setup_signing, session)  # fmt: skip
    print(f"skyherd companion: {args.mission} via {address}, "
          f"{'free-running' if args.free_run else 'lockstep'}; run folder {run_dir}", file=sys.stderr, flush=True)  # fmt: skip
    rc, error = fly_vehicle(
        mission, link, run_dir, frames, session, not args.free_run, args.wait_go
    )
    if folder is not None:  # on its own (not under `skyherd fly`): its own summary and plots
        from skyherd.report.fly import report

        report(run_dir, args, rc, error)
    return rc


def _run_formation(args, run_dir: Path, folder: RunFolder | None) -> int:
    """K vehicles (instances N..N+K-1) in lockstep, one link each (mission.runner)."""
    from skyherd.mission.runner import fly_formation, load_formation

    plan, params, homes = _built(folder, load_formation, args.plan, args.cell_m)
    if folder is not None:
        folder.write_config({"args": args_dict(args), "formation": params, "homes": homes})
    rc, error = fly_formation(
        plan, params, homes, run_dir, args.instance, args.signing_key, args.wait_go
    )
    if folder is not None:
        from skyherd.report.formation import formation_report

        formation_report(run_dir, rc, error)
    return rc


def _built(folder: RunFolder | None, build, *args):
    """`build(*args)`; its ValueError a UsageError, with the companion's own run folder removed
    (a usage error leaves no run folder)."""
    try:
        return build(*args)
    except ValueError as e:
        if folder is not None:
            shutil.rmtree(folder.path, ignore_errors=True)
        raise UsageError(str(e)) from None
