"""`skyherd fly`: fly a mission end to end through skyherd's own MAVLink client.

Default (the main job, `make run`): start the built-in quadrotor SITL in this process and fly
the ground-air mission: the learned policy keeps three UGVs in the camera's view through
MAVLink offboard, behind the safety net (scripts/fly_groundair.py). Other missions: a square
(scripts/fly_square.py), a K-vehicle formation (scripts/fly_formation.py), and the fixed-wing's
orbit (scripts/fly_orbit.py). `--connect ADDRESS` flies an outside vehicle (another
`skyherd sitl`, PX4 SITL, a real autopilot) instead of the built-in one.
"""

from __future__ import annotations

import argparse

from hil.client import VehicleClient
from hil.link import LinkError, MavlinkLink, parse_address
from runio.runfolder import RunFolder, args_dict
from scripts.cli import UsageError
from scripts.fly_square import SquareMission, fly_square


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--mission",
        choices=["groundair", "square", "formation"],
        default="groundair",
        help="groundair: the learned policy keeps the UGVs in view behind the safety net "
        "(default); square: a 40 m square at 20 m; formation: K vehicles fly the SQL-SIE "
        "plan to their formation targets",
    )
    parser.add_argument(
        "--airframe",
        choices=["quadrotor", "fixedwing"],
        default="quadrotor",
        help="quadrotor (default) or fixedwing (JSBSim; flies the ground-air task as an orbit)",
    )
    parser.add_argument(
        "--connect",
        metavar="ADDRESS",
        help="fly an outside vehicle at this pymavlink address "
        "(e.g. udpin:127.0.0.1:14540) instead of the built-in SITL",
    )
    parser.add_argument("--instance", type=int, default=0, help="built-in SITL instance N")
    parser.add_argument(
        "--speedup",
        type=float,
        default=10.0,
        help="built-in SITL speed-up over wall time, >= 1 (default 10)",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation seed (default 0)")
    parser.add_argument("--runs-dir", default="runs", help="where run folders go")
    parser.add_argument(
        "--timeout", type=float, default=600.0, help="wall-clock limit for the whole flight [s]"
    )
    sq = parser.add_argument_group("square mission")
    sq.add_argument("--altitude", type=float, default=20.0, help="mission altitude [m]")
    sq.add_argument("--side", type=float, default=40.0, help="square side [m]")
    ga = parser.add_argument_group("ground-air mission")
    ga.add_argument("--policy", default=None, help="policy file (default: the one the repo keeps)")
    ga.add_argument("--envelope", default=None, help="constraint-set TOML for the safety net")
    ga.add_argument("--duration", type=float, default=60.0, help="policy flight time [s]")
    ga.add_argument(
        "--ugvs",
        default="composite",
        metavar="SCENARIO",
        help="UGV team: lateral, climb, descend, composite (the training scenarios; default "
        "composite) or groundsim:route|convoy|random|stopgo|speedoff|camouflage",
    )
    ga.add_argument(
        "--pilot",
        choices=["policy", "pid"],
        default="policy",
        help="policy: the learned policy (default); pid: the classic follower on image features",
    )
    ga.add_argument("--renderer", choices=["fast", "bullet"], default="fast")
    ga.add_argument("--zenoh-port", type=int, default=7447, help="Zenoh listen port (loopback)")
    ga.add_argument("--no-zenoh", action="store_true", help="do not publish camera frames")
    from scripts.fly_formation import add_formation_arguments

    add_formation_arguments(parser.add_argument_group("formation mission"))
    from scripts.fly_orbit import add_orbit_arguments

    add_orbit_arguments(parser.add_argument_group("fixed-wing orbit (--airframe fixedwing)"))


def run(args: argparse.Namespace) -> int:
    if args.connect is None and args.speedup < 1:
        raise UsageError(
            "--speedup must be >= 1 for the built-in SITL: a MAVLink client cannot keep up "
            "with an unpaced vehicle (offboard setpoints would time out)"
        )
    address = args.connect or f"udpin:127.0.0.1:{14540 + args.instance}"
    try:
        parse_address(address)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if args.airframe == "fixedwing" and args.mission != "groundair":
        raise UsageError(
            f"--mission {args.mission} is for the quadrotor; a fixed-wing flies the ground-air "
            "task as an orbit (drop --mission)"
        )
    if args.mission == "formation":
        return _run_formation(args)
    if args.airframe == "fixedwing":
        mission, parts = "orbit", {}
    elif args.mission == "square":
        if not (0 < args.altitude <= 120 and 0 < args.side <= 500):
            raise UsageError("--altitude must be in (0, 120] m and --side in (0, 500] m")
        mission = SquareMission(altitude=args.altitude, side=args.side)
        parts = {}
    else:
        mission, parts = _groundair_parts(args)

    run_dir = RunFolder("fly", root=args.runs_dir)
    run_dir.write_config(
        {"args": args_dict(args), "mission": mission, "address": address,
         **{k: v for k, v in parts.items() if k in ("supervisor_params", "envelope")}}
    )  # fmt: skip
    sitl = None
    if args.connect is None:
        sitl = _start_embedded_sitl(args)
    try:
        link = MavlinkLink.open(address, tlog=run_dir.file("telemetry.tlog"))
    except LinkError as e:
        if sitl:
            sitl.close()
        raise UsageError(f"{e}; is another skyherd or SITL using that port?") from None
    print(f"skyherd fly: run folder {run_dir.path}")
    ok = False
    session = None
    try:
        with VehicleClient(link) as client:
            if args.mission == "square":
                ok = fly_square(client, mission, run_dir, args.timeout)
            elif args.airframe == "fixedwing":
                from scripts.fly_orbit import run_orbit

                session, publisher = _open_zenoh(args)
                ok = run_orbit(args, client, run_dir, publisher)
            else:
                from scripts.fly_groundair import fly_groundair

                session, publisher = _open_zenoh(args, mission.vehicle)
                supervisor = parts["make_supervisor"](run_dir.events())
                ok = fly_groundair(client, mission, parts["policy"], supervisor, publisher,
                                   run_dir, args.seed, args.timeout)  # fmt: skip
    finally:
        if session is not None:
            session.close()
        if sitl:
            sitl.close()
    return 0 if ok else 1


def _run_formation(args) -> int:
    """K built-in vehicles, each with its own endpoints and client (instances 0..K-1)."""
    from scripts.fly_formation import run_formation

    if args.connect is not None:
        raise UsageError("--mission formation flies the built-in vehicles only; drop --connect")
    run_dir = RunFolder("fly", root=args.runs_dir)
    run_dir.write_config({"args": args_dict(args), "mission": "formation"})
    print(f"skyherd fly: run folder {run_dir.path}")
    return 0 if run_formation(args, run_dir) else 1


def _groundair_parts(args):
    """Load and check everything the ground-air mission needs before anything starts."""
    from policy.dqn import PolicyFileError, load_policy
    from policy.models import DEFAULT_POLICY
    from safety.config import ENVELOPE_DIR, EnvelopeFileError
    from safety.net import load_net, warm_up
    from scripts.fly_groundair import GroundAirMission

    if not 0 < args.duration <= 3600:
        raise UsageError("--duration must be in (0, 3600] s")
    from policy.groundair.scenarios import GROUNDSIM_SCENARIOS, SCENARIOS

    if args.ugvs not in SCENARIOS + GROUNDSIM_SCENARIOS:
        raise UsageError(
            f"--ugvs {args.ugvs!r} is not a team: use one of "
            + ", ".join(SCENARIOS + GROUNDSIM_SCENARIOS)
        )
    mission = GroundAirMission(
        scenario=args.ugvs, pilot=args.pilot, duration_s=args.duration, renderer=args.renderer
    )
    policy_path = args.policy or DEFAULT_POLICY
    try:
        policy = load_policy(policy_path)
    except PolicyFileError as e:
        raise UsageError(f"{e}; train one with `skyherd train ab` or pass --policy") from None
    env_path = args.envelope or ENVELOPE_DIR / "quadrotor_groundair.toml"
    try:
        probe = load_net("quadrotor", env_path)  # check the file before anything flies
    except (EnvelopeFileError, ValueError) as e:
        raise UsageError(f"{e}; fix the file or pass another --envelope") from None

    def make_supervisor(events):
        sup = load_net("quadrotor", env_path, events=events)
        warm_up(sup.envelope, sup.p)  # compile and set up now, not at the first switch in flight
        return sup

    return mission, {
        "policy": policy,
        "make_supervisor": make_supervisor,
        "supervisor_params": probe.p,
        "envelope": probe.envelope.spec.describe(),
    }


def _open_zenoh(args, vehicle: str = "uav0"):
    if args.no_zenoh:
        return None, None
    from perception.transport import FramePublisher, open_session, publisher_params
    from policy.groundair.params import TaskParams

    try:
        session = open_session(publisher_params(args.zenoh_port))
    except ValueError as e:
        raise UsageError(
            f"{e}; is another flight publishing? use --zenoh-port or --no-zenoh"
        ) from None
    return session, FramePublisher(session, vehicle, TaskParams().camera)


def _start_embedded_sitl(args):
    """The built-in vehicle on a background thread, with the standard endpoints."""
    from flight.airframes_registry import make_autopilot
    from flight.mavlink import EndpointConfig
    from flight.sitl import Sitl

    autopilot = make_autopilot(args.airframe, seed=args.seed, instance=args.instance)
    return Sitl(autopilot, EndpointConfig(instance=args.instance), speedup=args.speedup).start()
