"""`skyherd fly`: fly a mission end to end.

The main job (`make run`): `skyherd sim` (the built-in quadrotor, the UGV team, the camera on
Zenoh) and `skyherd companion` (detector → φ(s) → the learned policy → safety net → MAVLink)
start as two child processes on the embedded defaults (a Zenoh peer on loopback, no router),
in lockstep on the simulator's clock; `fly` watches them, stops them in order, and writes one
run folder with the summary and plots. `--mission square` flies a square the same way;
`--mission shepherd` herds the UGV flock (`--ugvs flock`) into a goal region (mission/shepherd.py,
docs/shepherding.md).

`--airframe fixedwing` flies the ground-air task as an orbit the same way (`skyherd sim
--airframe fixedwing`, `skyherd companion --mission orbit`: mission/orbit.py). `--mission
formation` starts K simulators and one companion (scripts/fly_formation.py). `--connect ADDRESS`
flies an outside autopilot (PX4, ArduPilot, another `skyherd sitl`) with the companion alone,
free-running on the autopilot's clock.
"""

from __future__ import annotations

import argparse
import dataclasses
import signal
import sys
from dataclasses import dataclass
from pathlib import Path

from skyherd.runio import args_dict, ports
from skyherd.runio.run import Interrupted
from skyherd.scripts.cli import UsageError, usage
from skyherd.scripts.fault_options import FAULTS
from skyherd.scripts.fly_options import FLY_WORLD, check_child, child_argv, flight_signing
from skyherd.scripts.options import add_options, opt
from skyherd.world.setup import SimSetup


@dataclass(frozen=True)
class FlyOptions:
    """`skyherd fly`'s own options (scripts.options); those it shares with `skyherd sim` are
    world.setup.SimSetup's (scripts.fly_options), the companion's scripts.companion's."""

    connect: str | None = opt(
        None,
        metavar="ADDRESS",
        help="fly an outside autopilot at this pymavlink address (e.g. "
        f"{ports.companion_address(0)}, tcp:127.0.0.1:5760) instead of the built-in vehicle",
    )
    world_link: str | None = opt(
        None,
        metavar="ADDRESS",
        help="with --connect: a second MAVLink link of the autopilot for the world (UGVs, "
        f"camera) built around it (default: {ports.GCS_STREAM} for a udp address, PORT+2 for "
        "tcp:HOST:PORT, i.e. ArduPilot's SERIAL1)",
    )
    world_system: int = opt(0, metavar="ID")
    """with --connect: the outside autopilot's MAVLink system id on the world link (0: the first
    autopilot heard)"""
    no_signing: bool = False
    """fly the built-in vehicle unsigned: no per-run key; any local process can then command the
    vehicle and forge frames (recorded in config.json and summary.md)"""
    foxglove: int | None = opt(None, metavar="PORT")
    """serve the flight live to Foxglove on ws://127.0.0.1:PORT (default: off)"""
    no_record: bool = False  # do not write flight.mcap
    runs_dir: str = "runs"  # where run folders go
    timeout: float = 600.0  # wall-clock limit for the whole flight [s] (> 0)
    no_zenoh: bool = opt(False, help=argparse.SUPPRESS)  # kept for old scripts
    renderer: str = opt("fast", choices=["fast", "bullet"], help=argparse.SUPPRESS)


OWN = ("airframe", "connect", "world_link", "world_system", "param", "signing_key", "no_signing")
OWN += ("instance", "speedup", "free_run", "latency", "seed", "cut_link", "cut_camera")
OWN += ("foxglove", "no_record", "runs_dir", "timeout", "zenoh_port", "no_zenoh", "ugvs")
OWN += ("renderer",)  # fly's options before its groups' (SimSetup's and FlyOptions' fields)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from skyherd.scripts.companion import add_arguments as companion_arguments
    from skyherd.scripts.fault_options import add_fault_arguments
    from skyherd.scripts.fly_options import FormationOptions, OrbitOptions

    add_options(parser, (SimSetup, FlyOptions), only=OWN, **FLY_WORLD)
    add_fault_arguments(parser.add_argument_group("faults in the simulation (flight/faults.py)"))
    missions = ("groundair", "square", "formation", "shepherd")
    companion_arguments(parser.add_argument_group("mission and companion"), False, missions)
    add_options(parser.add_argument_group("formation mission"), FormationOptions)
    orbit = parser.add_argument_group("fixed-wing orbit (--airframe fixedwing)")
    add_options(orbit, OrbitOptions)


def run(args: argparse.Namespace) -> int:
    from skyherd.runio.signals import KeptSignals

    # from its first line on a signal is kept, never raised half-way through a check, the run
    # folder or a child's start, and acted on at the next safe point (runio.signals.KeptSignals):
    # before the run folder that is "nothing was recorded"
    with KeptSignals() as kept:
        _check_own(args)
        if args.airframe == "fixedwing" and args.mission != "groundair":
            raise UsageError(f"--mission {args.mission} is for the quadrotor; a fixed-wing flies the ground-air task as an orbit (drop --mission)")  # fmt: skip
        if args.mission == "formation":
            from skyherd.scripts.fly_formation import run_formation

            return run_formation(args, kept)
        return run_two_processes(args, kept)


def nothing_recorded(signum: int) -> int:
    """Say that a signal (kept until now) stopped `fly` before its run folder was made; its
    exit code (128 + signum)."""
    from skyherd.runio.signals import interrupted

    rc, why = interrupted(Interrupted(signum))
    print(f"skyherd fly: INTERRUPTED: {why} before the flight started; nothing was recorded",
          flush=True)  # fmt: skip
    return rc


def _check_own(args) -> None:
    """fly's own options that no child checks (UsageError, one line); the instance's Zenoh
    port (runio.ports) when --zenoh-port is not given."""
    import math

    from skyherd.flight.clock import default_speedup

    args.zenoh_port = usage(ports.checked_zenoh_port, args.instance, args.zenoh_port)
    args.speedup = default_speedup(args.speedup, args.free_run or args.connect is not None)
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UsageError(
            f"--timeout {args.timeout:g}: a wall-clock limit in seconds, > 0 (default 600)"
        )


def _validate(args) -> tuple[list[str], list[str]]:
    """The children's argument lists, each checked by the child's own parser and checks
    (fly_options.check_child); UsageError before anything starts or is written. fly checks
    only what no child can know: the missions' combinations, the team, the pilot's files, the
    wind against the constraint set, --orbit-duration."""
    from skyherd.hil.addresses import world_link
    from skyherd.task.scenarios import FLOCK

    if args.mission == "shepherd":
        if args.connect is not None or args.airframe != "quadrotor":
            raise UsageError(
                "--mission shepherd flies the built-in quadrotor: drop --connect / --airframe"
            )
        if args.ugvs == "composite":  # the default team: the shepherd's is the flock
            args.ugvs = FLOCK
        if args.ugvs != FLOCK:
            raise UsageError(f"--mission shepherd herds --ugvs {FLOCK}, not {args.ugvs!r}")
    elif args.ugvs == FLOCK:
        raise UsageError(f"--ugvs {FLOCK} is the shepherding flock: fly it with --mission shepherd")
    if args.ugvs == "none":  # `skyherd sim`'s vehicle alone: no team, no camera
        raise UsageError("--ugvs none: a mission flies over a team; give --ugvs SCENARIO")
    orbit = args.airframe == "fixedwing"  # the ground-air task, flown as an orbit
    sim = {d: getattr(args, d) for d in TO_SIM} | {
        "signing_key": usage(flight_signing(args).checked_key_file)
    }
    sim["free_run"] = args.free_run or args.connect is not None
    if orbit:
        if args.ugvs != "composite":  # the default: the orbit's team is its own option
            raise UsageError(f"--ugvs {args.ugvs}: the fixed-wing's orbit flies over "
                             "--orbit-scenario (lateral or composite); drop --ugvs")  # fmt: skip
        sim["ugvs"] = args.orbit_scenario
    if args.connect is not None and args.mission == "groundair":
        sim["follow"] = usage(world_link, args.connect, args.world_link)
        sim["follow_system"] = args.world_system
    sim_args = child_argv("sim", **sim)
    if args.connect is None or args.mission == "groundair":  # before the team is built below
        check_child("sim", sim_args)
    if args.mission in ("groundair", "shepherd") and args.connect is None:
        _refuse_wind_above_limit(args)
    if args.policy is not None:
        from skyherd.mission.build import load_pilot_policy

        usage(load_pilot_policy, args.policy)
    if args.pilot.startswith("drill:"):  # a named drill of the flight's envelope
        from skyherd.mission.build import drill_pilot
        from skyherd.safety.config import fly_envelope

        usage(drill_pilot, args.pilot, usage(fly_envelope, args.envelope, args.airframe))
    if args.lost_ugv_search and (
        args.mission != "groundair" or orbit or args.pilot.startswith("drill:")
    ):
        raise UsageError(
            "--lost-ugv-search is for the ground-air mission's policy or pid pilot (quadrotor)"
        )
    comp = dict(mission=args.mission, duration=args.duration, altitude=args.altitude)
    if orbit:
        comp["duration"] = args.orbit_duration if args.orbit_duration is not None else 90.0
        if not 0 < comp["duration"] <= 3600:  # the companion's --duration is not this flag
            raise UsageError("--orbit-duration must be in (0, 3600] s")
        comp |= dict(mission="orbit", orbit_team=args.orbit_scenario, orbit_seed=args.seed)
        comp |= dict(orbit_no_land=args.orbit_no_land)
    elif args.altitude is None and args.mission == "groundair":
        from skyherd.task.params import TaskParams
        from skyherd.world.team import new_team, start_altitude

        task = TaskParams()
        comp["altitude"] = start_altitude(task, new_team(args.ugvs, args.seed, task.n_ugvs))
    comp |= {d: getattr(args, d) for d in TO_COMPANION} | {
        "shepherd_selector": args.shepherd_selector if args.mission == "shepherd" else None,
        "policy": args.policy and str(Path(args.policy).resolve()),
        "envelope": args.envelope and str(Path(args.envelope).resolve()),
        "no_camera": args.mission == "square" or args.no_camera,
        "zenoh_connect": f"tcp:{ports.LOOPBACK}:{args.zenoh_port}",
        "free_run": sim["free_run"],
        "signing_key": sim["signing_key"],
    }
    comp_args = child_argv("companion", **comp)
    check_child("companion", comp_args)
    return sim_args, comp_args


TO_SIM = tuple(f.name for f in dataclasses.fields(SimSetup) if f.name in OWN + FAULTS)
"""fly's options `skyherd sim` takes as they are given (its world.setup.SimSetup fields)."""
TO_COMPANION = ("pilot", "side", "instance", "connect", "lost_ugv_search", "configure_autopilot")
TO_COMPANION += ("setup_signing",)  # ... and the companion's


def _refuse_wind_above_limit(args) -> None:
    """UsageError when the mean wind asked for (--wind) is above the constraint set's wind
    limit (safety.config.check_mean_wind)."""
    from skyherd.flight.faults import parse_fault_args
    from skyherd.safety.config import check_mean_wind

    try:  # a fault flag's own message names it and its form
        plan = parse_fault_args(args.wind, args.gust, args.noise, args.fault, seed=args.seed)
        check_mean_wind(args.envelope, args.airframe, plan.wind.mean_ned, args.wind)
    except ValueError as e:
        raise UsageError(str(e)) from None


def run_two_processes(args: argparse.Namespace, kept) -> int:
    """Simulator and companion in lockstep; `kept`: fly's KeptSignals (keeping)."""
    from skyherd.runio.run import open_run_folder
    from skyherd.safety.config import flight_envelope_record

    sim_args, comp_args = _validate(args)  # the children's own checks too
    envelope = None  # the safety net's constraint set: (its spec, config.json's record)
    if args.mission in ("groundair", "shepherd"):
        envelope = usage(flight_envelope_record, args.envelope, args.airframe)
    if kept.signum is not None:  # nothing made, nothing started
        return nothing_recorded(kept.signum)
    folder = open_run_folder("fly", args.runs_dir)  # UsageError: not writable, full
    return _fly(args, folder.path, folder, sim_args, comp_args, envelope, kept)


def _fly(args, run_dir: Path, folder, sim_args, comp_args, envelope, kept) -> int:
    """The flight in its run folder: start, supervise, stop, report; every signal kept by
    `kept` until the children run, then acted on (Launch.supervise). `envelope`: the
    constraint set (its spec, config.json's record) or None."""
    from skyherd.report import ending
    from skyherd.runio import launch, signals
    from skyherd.scripts.cli import skyherd_cmd

    key = flight_signing(args).per_run_key(run_dir)
    if key is not None:  # handed to both programs
        sim_args += ["--signing-key", str(key)]
        comp_args += ["--signing-key", str(key)]
    folder.write_config({"args": args_dict(args), "argv": sys.argv, "sim": sim_args,
                         "companion": comp_args, "envelope": envelope and envelope[1],
                         "signing": flight_signing(args).mode()})  # fmt: skip
    ending.write_running(run_dir)
    print(f"skyherd fly: run folder {run_dir}", flush=True)
    recorder = None
    why = "interrupted (Ctrl-C)"
    kids = launch.Launch(kept)
    try:
        with kids:  # stopped on every way out, the companion first
            if args.connect is None or args.mission == "groundair":
                kids.start_sim("sim", skyherd_cmd("sim", *sim_args, "--run-dir", str(run_dir)),
                         run_dir / "sim.log")  # fmt: skip
            # the companion sets up meanwhile and says hello (the simulator's clock starts on
            # it) only once the recorder has subscribed: the recording holds the flight from
            # its start
            companion = kids.start_companion(skyherd_cmd(
                "companion", *comp_args, "--run-dir", str(run_dir), "--wait-go"), wait_go=True)  # fmt: skip
            if kids.sims:  # once the simulator says it runs (its Zenoh session is open)
                sim_up = lambda: kids.sims[0].said(SIM_STARTED)  # noqa: E731
                stop_waiting = lambda: kept.signum is not None or kids.ended()  # noqa: E731
                recorder = _recorder(args, run_dir, _key_file(sim_args), envelope and envelope[0],
                                     give_up=stop_waiting, ready=sim_up)  # fmt: skip
            companion.go()
            rc, why = kids.supervise(args.timeout)  # acts on a signal kept until now
    except KeyboardInterrupt as e:  # SIGINT, SIGTERM, SIGHUP (runio.launch): 128 + signum
        rc, why = signals.interrupted(e)
    finally:  # signals are kept again (Launch.__exit__): the report is written whole
        if recorder is not None:
            recorder.close()
    from skyherd.report.fly import report  # after the flight: not on the way to the launch

    plots: list = []  # made once the verdict and the ending are said (ending.make_plots)
    ok = ending.end_run(run_dir, report, args, rc, why, plots, why=why, sims=kids.sims,
                        recorder=recorder)  # fmt: skip
    ending.make_plots(run_dir, plots)
    return after_report(ok, rc, kept)


def after_report(ok: bool, rc: int, kept) -> int:
    """fly's exit code once the report is written (`ok`: the flight's verdict, `rc`: how it
    ended); a signal kept while the report was written makes it 128 + signum, said."""
    from skyherd.runio.signals import interrupted

    if rc <= 128 and kept.signum is not None:
        rc = interrupted(Interrupted(kept.signum))[0]
        print(f"skyherd fly: interrupted ({signal.Signals(kept.signum).name}) after the flight "
              "ended; its report above is whole", file=sys.stderr, flush=True)  # fmt: skip
    return 0 if ok and rc == 0 else (rc if rc > 128 else 1)


def _key_file(child_args: list[str]) -> str | None:
    """The signing key file handed to a child (None: unsigned)."""
    return (
        child_args[child_args.index("--signing-key") + 1] if "--signing-key" in child_args else None
    )


SIM_STARTED = "skyherd sim: instance"  # the simulator's line once its world runs (world.serve)


def _recorder(args, run_dir: Path, key_file: str | None, envelope, give_up, ready):
    """flight.mcap and the live view beside the two programs (record.flight_recording; None
    with --no-record and no --foxglove, or when it cannot start: the flight never depends on
    its recording), with the constraint set's fence and rows when `envelope` is a spec."""
    if args.no_record and args.foxglove is None:
        return None
    from skyherd.mission.connect import GaveUp, open_client
    from skyherd.record.flight_recording import record_flight

    def connect(params):
        try:
            return open_client(params, give_up=give_up)
        except GaveUp:  # supervise() says why (the signal, the child that ended)
            return None

    path = None if args.no_record else run_dir / "flight.mcap"
    return record_flight(args.zenoh_port, path, args.foxglove, key_file=key_file,
                         envelope=envelope, connect=connect, ready=ready, give_up=give_up)  # fmt: skip
