"""`skyherd sitl`: run one simulated vehicle with its MAVLink endpoints until interrupted
(flight.sitl_vehicle; ports for instance N in the PX4 SITL layout, system id 1+N; parameters
set over MAVLink persist per airframe and instance)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

from skyherd.flight.geo import DEFAULT_HOME, Home
from skyherd.flight.sitl_vehicle import default_state_dir
from skyherd.runio import UsageError, ports
from skyherd.scripts.cli import usage
from skyherd.scripts.options import add_options, opt


@dataclass(frozen=True)
class SitlOptions:
    """The options of `skyherd sitl` (scripts.options: one field, one option)."""

    airframe: str = opt("quadrotor", choices=["quadrotor", "fixedwing"])
    instance: int = 0  # vehicle instance N: system id 1+N, ports +N
    speedup: float = 1.0
    """simulation speed over wall time (>= 1, or 0 = as fast as possible); 1 by default, unlike
    fly and sim: the vehicle stands alone for ground stations and MAVSDK, which expect real
    time"""
    home: str = f"{DEFAULT_HOME.lat_deg},{DEFAULT_HOME.lon_deg},{DEFAULT_HOME.alt_m}"
    """home LAT,LON,ALT (degrees, degrees, metres AMSL)"""
    personality: str = opt("px4", choices=["px4", "ardupilot"])
    """present PX4 custom modes (default) or ArduCopter mode numbers"""
    bind: str = "127.0.0.1"  # address the sockets bind to (default 127.0.0.1)
    state_dir: Path | None = opt(
        None, help=f"parameter persistence root (default {default_state_dir()})"
    )
    duration: float | None = None  # stop after this many simulated seconds
    seed: int = 0
    runs_dir: Path = opt(Path("runs"), aliases=("--runs",))
    """where run folders go (runs); --runs is the older name"""
    no_tlog: bool = False  # do not write telemetry.tlog
    params: Path | None = opt(None, metavar="FILE")
    """TOML [params] overrides at start, e.g. flight/airframes/px4_standin.toml (the PX4
    stand-in set); default none"""
    signing_key: Path | None = None
    """MAVLink 2 signing key file (32 bytes): signing on (default: none, or the key a
    SETUP_SIGNING saved in --state-dir)"""


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from skyherd.scripts.fault_options import add_fault_arguments

    add_options(parser, SitlOptions)
    add_fault_arguments(parser)  # --wind --gust --noise --fault (docs/quadrotor.md, faults)


def run(args: argparse.Namespace) -> int:
    from skyherd.flight.airframes_registry import AirframeUnavailable, make_autopilot
    from skyherd.flight.clock import SimClock
    from skyherd.flight.mavlink import EndpointConfig, Personality
    from skyherd.flight.sitl import Sitl
    from skyherd.flight.sitl_vehicle import (
        links_table,
        run_summary,
        run_until_stopped,
        saved_params,
        saved_params_line,
    )
    from skyherd.runio.run import open_run_folder
    from skyherd.scripts.fault_options import plan_from_args

    if not (args.speedup == 0 or args.speedup >= 1):
        raise UsageError(f"--speedup must be 0 (as fast as possible) or >= 1, got {args.speedup}")
    usage(ports.check_instance, args.instance)  # one wording for every command
    if args.duration is not None and not args.duration > 0:
        raise UsageError("--duration must be a positive number of simulated seconds")
    try:
        home = Home.parse(args.home)
    except ValueError as e:
        raise UsageError(f"--home: {e}; give LAT,LON,ALT like -35.36,149.16,584") from e
    plan = usage(plan_from_args, args, args.seed)  # flight.faults.FaultSpecError
    try:
        ap = make_autopilot(
            args.airframe, clock=SimClock(), home=home, seed=args.seed, instance=args.instance,
            faults=plan, params_file=args.params,
        )  # fmt: skip
    except AirframeUnavailable as e:
        raise UsageError(f"{e}; use --airframe quadrotor") from e
    except ValueError as e:
        raise UsageError(f"--params: {e}") from e

    folder = open_run_folder("sitl", args.runs_dir)  # UsageError: not writable, full
    state_dir = args.state_dir if args.state_dir is not None else default_state_dir()
    config = EndpointConfig(
        instance=args.instance,
        personality=Personality(args.personality),
        bind_host=args.bind,
        state_dir=state_dir,
        tlog=None if args.no_tlog else folder.file("telemetry.tlog"),
        signing_key=args.signing_key,
    )
    saved = saved_params(config, ap.airframe)
    folder.write_config({"airframe": args.airframe, "speedup": args.speedup, "home": home,
                         "seed": args.seed, "endpoint": config, "control_dt": ap.control_dt,
                         "faults": plan, "fault_args": plan.to_args(),
                         "params_file": args.params, "params_saved": saved})  # fmt: skip
    try:
        sitl = Sitl(ap, config, speedup=args.speedup)
    except OSError as e:
        raise UsageError(
            f"{e}; is another instance running? try --instance {args.instance + 1}"
        ) from e
    except ValueError as e:  # flight.mavlink.signing.SigningError: a bad key file
        raise UsageError(str(e)) from e
    print(f"skyherd sitl: {args.airframe}, system id {config.system_id}, {args.personality} personality, "
          f"speed-up {args.speedup:g}, run folder {folder.path}")  # fmt: skip
    print(links_table(config), flush=True)
    if (line := saved_params_line(saved)) is not None:
        print(line, flush=True)
    with sitl:
        stats = run_until_stopped(sitl, args.duration)
    table = run_summary(sitl, stats)
    folder.write_summary("# skyherd sitl\n\n" + table)
    print(table)
    print(f"skyherd sitl: stopped at t = {sitl.clock.t:.1f} s simulated", file=sys.stderr)
    return 0
