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
import os
import signal
import sys
from pathlib import Path

from skyherd.runio import args_dict, ports
from skyherd.runio.constants import GCS_REMOTE_PORT, LOCKSTEP_LATENCY_S, LOOPBACK
from skyherd.runio.run import Interrupted
from skyherd.scripts.cli import UsageError

# --world-link's default beside a udp --connect: the autopilot's ground-station stream
GCS_WORLD_LINK = f"udpin:{LOOPBACK}:{GCS_REMOTE_PORT}"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--airframe",
        choices=["quadrotor", "fixedwing"],
        default="quadrotor",
        help="quadrotor, or fixedwing (JSBSim; flies the ground-air task as an orbit)",
    )
    parser.add_argument("--connect", metavar="ADDRESS",
                        help="fly an outside autopilot at this pymavlink address (e.g. "
                        f"{ports.companion_address(0)}, "
                        "tcp:127.0.0.1:5760) instead of the built-in vehicle")  # fmt: skip
    parser.add_argument("--world-link", metavar="ADDRESS", default=None,
                        help="with --connect: a second MAVLink link of the autopilot for the world (UGVs, "
                        f"camera) built around it (default: {GCS_WORLD_LINK} for a udp address, "
                        "PORT+2 for tcp:HOST:PORT, i.e. ArduPilot's SERIAL1)")  # fmt: skip
    parser.add_argument(
        "--world-system",
        type=int,
        default=0,
        metavar="ID",
        help="with --connect: the outside autopilot's MAVLink system id on the world link (0: the first autopilot heard)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a parameter of the built-in autopilot at start (repeatable), e.g. COM_OF_LOSS_T=3",
    )
    parser.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing key file (32 bytes) for the vehicle (every vehicle of a formation), "
        "the companion, the world's link and the Zenoh records' MACs (default with the built-in "
        "vehicle: a new key per run, <run>/signing.key)",
    )
    parser.add_argument(
        "--no-signing",
        action="store_true",
        help="fly the built-in vehicle unsigned: no per-run key; any local process can then "
        "command the vehicle and forge frames (recorded in config.json and summary.md)",
    )
    parser.add_argument("--instance", type=int, default=0,
                        help=f"built-in vehicle instance N in [0, {ports.MAX_INSTANCE}]: its MAVLink ports "
                        f"{ports.MAVLINK_PORTS_HELP} and its {ports.ZENOH_PORT_HELP}")  # fmt: skip
    from skyherd.flight.clock import SPEEDUP_HELP

    parser.add_argument("--speedup", type=float, default=None, metavar="S",
                        help=SPEEDUP_HELP + "; --connect free-runs")  # fmt: skip
    parser.add_argument(
        "--free-run",
        action="store_true",
        help="the simulator does not wait for the companion (its lag is measured instead)",
    )
    parser.add_argument(
        "--latency",
        type=float,
        default=LOCKSTEP_LATENCY_S,
        metavar="S",
        help="lockstep: the companion's declared compute latency [s of simulation time]",
    )
    parser.add_argument("--seed", type=int, default=0, help="simulation seed")
    parser.add_argument(
        "--cut-link",
        action="append",
        default=[],
        metavar="T:D",
        help="cut the companion's MAVLink link both ways at simulation time T [s] for D [s]",
    )
    parser.add_argument(
        "--cut-camera",
        action="append",
        default=[],
        metavar="T:D",
        help="stop the camera's frames at T [s] for D [s]",
    )
    parser.add_argument(
        "--foxglove",
        type=int,
        default=None,
        metavar="PORT",
        help="serve the flight live to Foxglove on ws://127.0.0.1:PORT (default: off)",
    )
    parser.add_argument("--no-record", action="store_true", help="do not write flight.mcap")
    parser.add_argument("--runs-dir", default="runs", help="where run folders go")
    parser.add_argument(
        "--timeout",
        type=float,
        default=600.0,
        help="wall-clock limit for the whole flight [s] (> 0)",
    )
    parser.add_argument("--zenoh-port", type=int, default=None,
                        help=f"the simulator's Zenoh port on {ports.LOOPBACK} (default: {ports.ZENOH_BASE}+N for --instance N)")  # fmt: skip
    parser.add_argument(
        "--no-zenoh", action="store_true", help=argparse.SUPPRESS
    )  # kept for old scripts
    parser.add_argument("--ugvs", default="composite", metavar="SCENARIO",
                        help="UGV team: lateral, climb, descend, composite (the training scenarios), "
                        "groundsim:route|convoy|random|stopgo|speedoff|camouflage, or flock (--mission shepherd's "
                        "default: a flock that flees the UAV, groundsim/flock.py)")  # fmt: skip
    parser.add_argument(
        "--renderer", choices=["fast", "bullet"], default="fast", help=argparse.SUPPRESS
    )
    from skyherd.scripts.fault_options import add_fault_arguments

    add_fault_arguments(parser.add_argument_group("faults in the simulation (flight/faults.py)"))
    from skyherd.scripts.companion import add_arguments as companion_arguments

    companion_arguments(parser.add_argument_group("mission and companion"), standalone=False,
                        missions=("groundair", "square", "formation", "shepherd"))  # fmt: skip
    from skyherd.scripts.fly_options import add_formation_arguments, add_orbit_arguments

    add_formation_arguments(parser.add_argument_group("formation mission"))
    add_orbit_arguments(parser.add_argument_group("fixed-wing orbit (--airframe fixedwing)"))


def run(args: argparse.Namespace) -> int:
    _check_own(args)
    if args.airframe == "fixedwing" and args.mission != "groundair":
        raise UsageError(f"--mission {args.mission} is for the quadrotor; a fixed-wing flies the ground-air task as an orbit (drop --mission)")  # fmt: skip
    if args.mission == "formation":
        from skyherd.scripts.fly_formation import run_formation

        return run_formation(args)
    return run_two_processes(args)


def _check_own(args) -> None:
    """fly's own options that no child checks (UsageError, one line); the instance's Zenoh
    port (runio.ports) when --zenoh-port is not given."""
    import math

    from skyherd.flight.clock import default_speedup

    try:
        args.zenoh_port = ports.checked_zenoh_port(args.instance, args.zenoh_port)
    except ValueError as e:
        raise UsageError(str(e)) from None
    args.speedup = default_speedup(args.speedup, args.free_run or args.connect is not None)
    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise UsageError(
            f"--timeout {args.timeout:g}: a wall-clock limit in seconds, > 0 (default 600)"
        )


def check_children(args, sim_args: list[str], comp_args: list[str]) -> None:
    """Each child's own parser and checks on the arguments fly passes it (scripts.sim and
    scripts.companion `check_args`), before anything starts or is written: UsageError with the
    child's one-line reason."""
    from skyherd.scripts import companion, sim

    if args.connect is None or args.mission == "groundair":  # the simulator starts
        why = sim.check_args(sim_args)
        if why:
            raise UsageError(why)
    why = companion.check_args(comp_args)
    if why:
        raise UsageError(why)


def _validate(args) -> tuple[list[str], list[str]]:
    """The children's argument lists; UsageError before anything starts or is written."""
    from skyherd.hil.link import link_address
    from skyherd.task.scenarios import FLOCK, TEAMS

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
    if args.connect is not None:
        try:
            link_address(args.connect)
        except ValueError as e:
            raise UsageError(str(e)) from None
    if args.connect is None and not (args.speedup == 0 or args.speedup >= 1):
        raise UsageError("--speedup must be 0 (as fast as possible) or >= 1")
    if args.free_run and args.speedup == 0:
        raise UsageError("--free-run needs a pacer: give --speedup >= 1")
    if args.ugvs not in TEAMS:
        raise UsageError(f"--ugvs {args.ugvs!r} is not a team: use one of " + ", ".join(TEAMS))
    if not 0 < args.duration <= 36000:
        raise UsageError("--duration must be in (0, 36000] s")
    if args.mission == "square":
        alt = 20.0 if args.altitude is None else args.altitude
        if not (0 < alt <= 120 and 0 < args.side <= 500):
            raise UsageError("--altitude must be in (0, 120] m and --side in (0, 500] m")
    if args.mission in ("groundair", "shepherd") and args.connect is None:
        _refuse_wind_above_limit(args)
    if args.policy is not None:
        from skyherd.mission.build import load_pilot_policy

        try:
            load_pilot_policy(args.policy)
        except ValueError as e:
            raise UsageError(str(e)) from None
    if args.pilot.startswith("drill:"):  # a named drill of the flight's envelope
        from skyherd.mission.build import drill_pilot
        from skyherd.safety.config import EnvelopeFileError, fly_envelope_path, load_envelope

        try:
            spec, _ = load_envelope(args.envelope or fly_envelope_path(args.airframe))
            drill_pilot(args.pilot, spec)
        except (EnvelopeFileError, ValueError) as e:
            raise UsageError(str(e)) from None
    orbit = args.airframe == "fixedwing"  # the ground-air task, flown as an orbit
    altitude = args.altitude
    if altitude is None and args.mission == "groundair" and not orbit:
        from skyherd.task.params import TaskParams
        from skyherd.world.team import new_team, start_altitude

        task = TaskParams()
        altitude = start_altitude(task, new_team(args.ugvs, args.seed, task.n_ugvs))
    comp = ["--mission", args.mission, "--pilot", args.pilot, "--duration", repr(args.duration),
            "--side", repr(args.side), "--instance", str(args.instance)]  # fmt: skip
    comp += ["--altitude", repr(altitude)] if altitude is not None else []
    comp += ["--shepherd-selector", args.shepherd_selector] if args.mission == "shepherd" else []
    if args.lost_ugv_search:
        if args.mission != "groundair" or orbit or args.pilot.startswith("drill:"):
            raise UsageError(
                "--lost-ugv-search is for the ground-air mission's policy or pid pilot (quadrotor)"
            )
        comp += ["--lost-ugv-search"]
    comp += ["--policy", str(Path(args.policy).resolve())] if args.policy else []
    comp += ["--envelope", str(Path(args.envelope).resolve())] if args.envelope else []
    comp += ["--configure-autopilot"] if args.configure_autopilot else []
    comp += ["--setup-signing"] if args.setup_signing else []
    if args.mission == "square" or args.no_camera:
        comp += ["--no-camera"]
    sim = ["--instance", str(args.instance), "--seed", str(args.seed), "--ugvs", args.ugvs,
           "--speedup", repr(args.speedup), "--latency", repr(args.latency),
           "--zenoh-port", str(args.zenoh_port)]  # fmt: skip
    if orbit:
        duration = args.orbit_duration if args.orbit_duration is not None else 90.0
        if not 0 < duration <= 3600:
            raise UsageError("--orbit-duration must be in (0, 3600] s")
        comp[1] = "orbit"
        comp[comp.index("--duration") + 1] = repr(duration)
        comp += ["--orbit-team", args.orbit_scenario, "--orbit-seed", str(args.seed)]
        comp += ["--orbit-no-land"] if args.orbit_no_land else []
        sim[sim.index("--ugvs") + 1] = args.orbit_scenario
        sim += ["--airframe", "fixedwing"]
    key = check_signing(args)
    if key is not None:
        sim += ["--signing-key", key]
        comp += ["--signing-key", key]
    for item in args.param:
        sim += ["--param", item]
    for item in args.cut_link:
        sim += ["--cut-link", item]
    for item in args.cut_camera:
        sim += ["--cut-camera", item]
    for flag in ("wind", "gust", "noise"):
        if getattr(args, flag):
            sim += [f"--{flag}", getattr(args, flag)]
    for item in args.fault:
        sim += ["--fault", item]
    if args.free_run or args.connect is not None:
        sim += ["--free-run"]
        comp += ["--free-run"]
    if args.connect is not None:
        comp += ["--connect", args.connect]
        if args.mission == "groundair":
            sim += ["--follow", world_link(args), "--follow-system", str(args.world_system)]
    comp += ["--zenoh-connect", f"tcp:{ports.LOOPBACK}:{args.zenoh_port}"]
    return sim, comp


def check_signing(args) -> str | None:
    """The signing options checked (UsageError, one line): the absolute path of the
    --signing-key file, or None (a per-run key, or --no-signing)."""
    from skyherd.flight.mavlink.signing import SigningError, load_key

    if args.signing_key and args.no_signing:
        raise UsageError("--signing-key and --no-signing contradict each other: drop one")
    if args.setup_signing and (args.connect is None or not args.signing_key):
        raise UsageError("--setup-signing gives an outside autopilot your key: it needs "
                         "--connect ADDRESS and --signing-key FILE (the built-in vehicle is "
                         "signed by default)")  # fmt: skip
    if not args.signing_key:
        return None
    try:
        load_key(Path(args.signing_key))
    except SigningError as e:
        raise UsageError(f"--signing-key: {e}") from None
    return str(Path(args.signing_key).resolve())


def _key_file(child_args: list[str]) -> str | None:
    """The signing key file handed to a child (None: unsigned)."""
    return (
        child_args[child_args.index("--signing-key") + 1] if "--signing-key" in child_args else None
    )


def signing_mode(args) -> str:
    """How this flight is signed, as config.json and summary.md say it."""
    if args.signing_key:
        return f"key file {Path(args.signing_key).resolve()}"
    if args.no_signing:
        return "off (--no-signing)"
    if args.connect is not None:
        return "off (outside autopilot: give --signing-key FILE with the autopilot's key)"
    return "on (per-run key)"


def per_run_key(args, run_dir: Path) -> Path | None:
    """With the built-in vehicle(s) and neither --signing-key nor --no-signing: a new key
    `<run>/signing.key` (32 random bytes, mode 0600) for every program of the flight."""
    from skyherd.flight.mavlink.signing import KEY_LEN, save_key

    if args.signing_key or args.no_signing or args.connect is not None:
        return None
    path = run_dir / SIGNING_KEY_FILE
    save_key(path, os.urandom(KEY_LEN))
    return path


def _refuse_wind_above_limit(args) -> None:
    """UsageError when the mean wind asked for (--wind) is above the constraint set's wind
    limit ([guards] wind_limit_mps): the net's envelope assumes braking that such a wind takes
    away. Wind that rises later (--fault wind@T:...) is the net's to judge in flight."""
    from skyherd.flight.faults import parse_fault_args
    from skyherd.safety.config import fly_envelope_path, load_envelope

    try:
        plan = parse_fault_args(args.wind, args.gust, args.noise, args.fault, seed=args.seed)
    except ValueError as e:  # a fault flag: its own message names it and its form
        raise UsageError(str(e)) from None
    try:
        spec, _ = load_envelope(args.envelope or fly_envelope_path(args.airframe))
    except ValueError as e:
        raise UsageError(f"{e}; fix it or pass another --envelope") from None
    w = plan.wind.mean_ned
    speed = (w[0] ** 2 + w[1] ** 2) ** 0.5
    limit = spec.guards.wind_limit_mps
    if limit is not None and speed > limit:
        raise UsageError(
            f"--wind {args.wind}: {speed:.1f} m/s is above the {spec.airframe}'s wind limit "
            f"{limit:g} m/s ({spec.name} {spec.version}, [guards] wind_limit_mps); fly in "
            f"{limit:g} m/s or less, or with a constraint set stated for this wind (--envelope)"
        )


def world_link(args) -> str:
    """The MAVLink link the world follows an outside vehicle on (--world-link, or a default)."""
    from skyherd.hil.link import link_address

    if args.world_link:
        try:
            link_address(args.world_link)
        except ValueError as e:
            raise UsageError(f"--world-link: {e}") from None
        return args.world_link
    a = link_address(args.connect)
    if a.scheme == "tcp":
        return f"tcp:{a.host}:{a.port + 2}"
    if a.scheme in ("udpin", "udpout", "udp"):
        return GCS_WORLD_LINK
    raise UsageError("the ground-air mission around a serial autopilot needs --world-link ADDRESS")


SIGNING_KEY_FILE = "signing.key"  # the per-run key in the run folder


def run_two_processes(args: argparse.Namespace) -> int:
    from skyherd.scripts import waysout

    # a signal from here on is kept, never raised half-way through making the folder or
    # starting a child, and acted on at the next safe point (waysout.KeptSignals)
    with waysout.KeptSignals() as kept:
        sim_args, comp_args = _validate(args)
        check_children(args, sim_args, comp_args)
        envelope = _envelope(args) if args.mission in ("groundair", "shepherd") else None
        if kept.signum is not None:  # nothing made, nothing started
            rc, why = waysout.interrupted(Interrupted(kept.signum))
            print(f"skyherd fly: INTERRUPTED: {why} before the flight started; nothing was "
                  "recorded", flush=True)  # fmt: skip
            return rc
        folder = waysout.open_run_folder("fly", args.runs_dir)  # UsageError: not writable, full
        return _fly(args, folder.path, folder, sim_args, comp_args, envelope, kept)


def _fly(args, run_dir: Path, folder, sim_args, comp_args, envelope, kept) -> int:
    """The flight in its run folder: start, supervise, stop, report; every signal kept by
    `kept` until the children run, then acted on (Launch.supervise)."""
    from skyherd.runio import launch
    from skyherd.scripts import waysout
    from skyherd.scripts.cli import skyherd_cmd

    key = per_run_key(args, run_dir)
    if key is not None:  # handed to both programs
        sim_args += ["--signing-key", str(key)]
        comp_args += ["--signing-key", str(key)]
    folder.write_config({"args": args_dict(args), "argv": sys.argv, "sim": sim_args,
                         "companion": comp_args, "envelope": envelope,
                         "signing": signing_mode(args)})  # fmt: skip
    waysout.write_running(run_dir)
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
                recorder = _recorder(args, run_dir, _key_file(sim_args), give_up=stop_waiting,
                                     ready=sim_up)  # fmt: skip
            companion.go()
            rc, why = kids.supervise(args.timeout)  # acts on a signal kept until now
    except KeyboardInterrupt as e:  # SIGINT, SIGTERM, SIGHUP (runio.launch): 128 + signum
        rc, why = waysout.interrupted(e)
    finally:  # signals are kept again (Launch.__exit__): the report is written whole
        if recorder is not None:
            recorder.close()
    from skyherd.report.fly import report  # after the flight: not on the way to the launch

    plots: list = []  # made once the verdict and the ending are said (make_plots)
    ok = waysout.report_safely(report, run_dir, args, rc, why, plots, why=why)  # never raises
    output = [ln for c in kids.sims for ln in (c.lines or ())]  # kept in memory
    lines = waysout.ending_lines(run_dir, output=output, cut=waysout.recording_cut(recorder))
    waysout.append_ending(run_dir, lines)
    make_plots(plots)
    if plots:  # report.html again, now with the figures made after the verdict
        from skyherd.report.page import write_report_html

        write_report_html(run_dir)
    if rc <= 128 and kept.signum is not None:  # a signal while the report was written
        rc = waysout.interrupted(Interrupted(kept.signum))[0]
        print(f"skyherd fly: interrupted ({signal.Signals(kept.signum).name}) after the flight "
              "ended; its report above is whole", file=sys.stderr, flush=True)  # fmt: skip
    return 0 if ok and rc == 0 else (rc if rc > 128 else 1)


def make_plots(plots: list) -> None:
    """The report's plots, (file name, call) each, after the verdict is printed: matplotlib
    (its import and drawing) is off the way to the verdict. A plot that fails is said on
    stderr; the flight's verdict and exit code stand."""
    for name, plot in plots:
        try:
            plot()
        except Exception as e:  # noqa: BLE001 - a plot never changes how the flight ended
            print(f"skyherd fly: {name} was not made ({type(e).__name__}: {e})", file=sys.stderr,
                  flush=True)  # fmt: skip


def _envelope(args) -> dict:
    """The safety net's constraint set (name, version, rows) for config.json; UsageError if bad."""
    from skyherd.safety.config import EnvelopeFileError, fly_envelope_path, load_envelope

    path = args.envelope or fly_envelope_path(args.airframe)
    try:
        spec, _ = load_envelope(path)
    except (EnvelopeFileError, ValueError) as e:
        raise UsageError(f"{e}; fix the file or pass another --envelope") from None
    if spec.airframe != args.airframe:
        raise UsageError(
            f"--envelope {path} is for a {spec.airframe}; this flight is a {args.airframe}"
        )
    return {"path": str(Path(path).resolve()), **spec.describe()}


class _Recording:
    """flight.mcap (and the live Foxglove view) from the flight's Zenoh keys, in this process."""

    def __init__(self, session, recorder):
        self.session, self.recorder = session, recorder

    def close(self) -> None:
        self.recorder.close()
        self.session.close()


SIM_STARTED = "skyherd sim: instance"  # the simulator's line once its world runs (scripts.sim)
SIM_START_PATIENCE_S = 120.0  # wall time the recorder waits for that line [s]
SIM_START_POLL_S = 0.02  # ... looking this often [wall s]


def _recorder(args, run_dir: Path, key_file: str | None = None, give_up=None, ready=None):
    """A ZenohRecorder beside the two programs (None with --no-record and no --foxglove, or
    when it cannot start: the flight never depends on its recording); with the flight's key
    file it records only authentic frames, UGV states and clock. It connects once `ready()`
    is True (the simulator's session listens; never a stranger on its port), and stops
    waiting when `give_up()` is True (a signal came, or a child ended: supervise() says which
    at once)."""
    if args.no_record and args.foxglove is None:
        return None
    try:
        import time

        from skyherd.flight.mavlink.signing import load_key

        key = load_key(Path(key_file)) if key_file else None
        from skyherd.mission.connect import GaveUp, open_client
        from skyherd.perception.transport import subscriber_params
        from skyherd.record import LiveServer, ZenohRecorder

        deadline = time.monotonic() + SIM_START_PATIENCE_S
        while ready is not None and not ready() and time.monotonic() < deadline:
            if give_up is not None and give_up():
                return None
            time.sleep(SIM_START_POLL_S)
        params = subscriber_params(f"tcp/127.0.0.1:{args.zenoh_port}")
        try:
            session = open_client(dataclasses.replace(params, mode="client"), give_up=give_up)
        except GaveUp:  # supervise() says why (the signal, the child that ended)
            return None
        also = [LiveServer(args.foxglove)] if args.foxglove is not None else []
        path = None if args.no_record else run_dir / "flight.mcap"
        if also:
            print(
                f"skyherd fly: live view on {also[0].url} (Foxglove: open connection)", flush=True
            )
        rec = ZenohRecorder(session, "uav0", path, also=also, key=key)
        if args.mission in ("groundair", "shepherd"):  # the fence and the envelope's rows
            from skyherd.safety.config import fly_envelope_path, load_envelope

            rec.log.geometry(
                0.0, load_envelope(args.envelope or fly_envelope_path(args.airframe))[0]
            )
        return _Recording(session, rec)
    except Exception as e:  # noqa: BLE001 - say so and fly without a recording
        print(f"skyherd fly: no flight.mcap ({type(e).__name__}: {e})", file=sys.stderr)
        return None
