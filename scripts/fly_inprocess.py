"""The mission that still flies in one process: the fixed-wing orbit (scripts/fly_orbit.py), the
built-in vehicle on a background thread and skyherd's threaded MAVLink client. (The ground-air,
square and formation missions fly as separate programs in lockstep: scripts/fly.py,
scripts/fly_formation.py.)"""

from __future__ import annotations

import argparse

from hil.client import VehicleClient
from hil.link import LinkError, MavlinkLink, parse_address
from runio import RunFolder, args_dict
from scripts.cli import UsageError


def run_inprocess(args: argparse.Namespace) -> int:
    if args.connect is None and args.speedup < 1:
        raise UsageError(
            "--speedup must be >= 1 for this mission: its MAVLink client cannot keep up with an "
            "unpaced vehicle (offboard setpoints would time out)"
        )
    address = args.connect or f"udpin:127.0.0.1:{14540 + args.instance}"
    try:
        parse_address(address)
    except ValueError as e:
        raise UsageError(str(e)) from None
    run_dir = RunFolder("fly", root=args.runs_dir)
    run_dir.write_config({"args": args_dict(args), "mission": "orbit", "address": address})
    sitl = None if args.connect is not None else _start_embedded_sitl(args)
    try:
        link = MavlinkLink.open(address, tlog=run_dir.file("telemetry.tlog"))
    except LinkError as e:
        if sitl:
            sitl.close()
        raise UsageError(f"{e}; is another skyherd or SITL using that port?") from None
    print(f"skyherd fly: run folder {run_dir.path}")
    session = None
    try:
        with VehicleClient(link) as client:
            from scripts.fly_orbit import run_orbit

            session, publisher = _open_zenoh(args)
            ok = run_orbit(args, client, run_dir, publisher)
    finally:
        if session is not None:
            session.close()
        if sitl:
            sitl.close()
    return 0 if ok else 1


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
