"""`skyherd sim`: the world — one vehicle with its autopilot and MAVLink endpoints, the UGV team,
the downward camera on Zenoh — owning the one simulation clock, until interrupted.

With `--lockstep` (the default) the simulation holds at every camera frame for the companion's
decision (`skyherd companion` closes each tick), so a flight is the same at any speed-up and
any machine load; `--free-run` steps on the pacer alone, as a real autopilot would, and
measures how late the companion's setpoints act.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys

from skyherd.flight.clock import SPEEDUP_HELP, default_speedup
from skyherd.runio import RunFolder, args_dict, ports
from skyherd.runio.constants import CAMERA_HZ, LOCKSTEP_LATENCY_S
from skyherd.scripts.cli import UsageError, check_with

DEFAULT_ZENOH_PORT = ports.ZENOH_BASE  # instance 0's; instance N listens on ZENOH_BASE+N


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--airframe",
        choices=["quadrotor", "fixedwing"],
        default="quadrotor",
        help="the vehicle: the quadrotor (downward camera) or the JSBSim fixed-wing (its camera "
        "on a pan-tilt gimbal pointed where a client sets the ROI: DO_SET_ROI_LOCATION)",
    )
    parser.add_argument(
        "--instance",
        type=int,
        default=0,
        help=f"vehicle instance N in [0, {ports.MAX_INSTANCE}]: {ports.MAVLINK_PORTS_HELP}, "
        f"{ports.ZENOH_PORT_HELP} and system id 1+N",
    )
    parser.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed of the vehicle, the UGV team and every random source",
    )
    parser.add_argument(
        "--ugvs",
        default="composite",
        metavar="SCENARIO",
        help="UGV team: lateral, climb, descend, composite, groundsim:route|convoy|random|stopgo|speedoff|camouflage, "
        "flock (flees the UAV: groundsim/flock.py); "
        "none: the vehicle alone (no team, no camera, no Zenoh session)",
    )
    parser.add_argument(
        "--home",
        default=None,
        metavar="LAT,LON,ALT",
        help="the vehicle's home [deg, deg, m AMSL] (default: the project's default home)",
    )
    parser.add_argument(
        "--ugv-start",
        default="offboard",
        metavar="WHEN",
        help="when the UGVs start to drive: 'offboard' (when the vehicle is handed to the companion: "
        "OFFBOARD for the built-in vehicle; beside --follow or --autopilot, the companion's first "
        "decision on skyherd/<vehicle>/decision) or a simulation time [s] (default offboard)",
    )
    parser.add_argument("--speedup", type=float, default=None, metavar="S", help=SPEEDUP_HELP)
    parser.add_argument(
        "--camera-hz",
        type=float,
        default=CAMERA_HZ,
        help="camera frames per simulated second (the companion's tick) (default %(default)s)",
    )
    parser.add_argument(
        "--free-run",
        action="store_true",
        help="do not wait for the companion (measure its lag instead)",
    )
    parser.add_argument(
        "--latency",
        type=float,
        default=LOCKSTEP_LATENCY_S,
        metavar="S",
        help="lockstep: the companion's declared compute latency [s of simulation time]",
    )
    parser.add_argument(
        "--duration",
        type=float,
        default=None,
        metavar="S",
        help="stop after this much simulation time [s] (default: until interrupted)",
    )
    parser.add_argument(
        "--zenoh-port",
        type=int,
        default=None,
        help=f"Zenoh listen port on {ports.LOOPBACK} (default: {ports.ZENOH_BASE}+N for --instance N)",
    )
    parser.add_argument(
        "--zenoh-config",
        default=None,
        metavar="FILE",
        help="a Zenoh JSON5 configuration instead (e.g. a router for two hosts; docs/topology.md)",
    )
    parser.add_argument(
        "--bind", default="127.0.0.1", metavar="HOST", help="address the MAVLink sockets bind to"
    )
    parser.add_argument(
        "--remote",
        default="127.0.0.1",
        metavar="HOST",
        help="host the companion and the ground station listen on",
    )
    parser.add_argument(
        "--follow",
        default=None,
        metavar="ADDRESS",
        help="no built-in vehicle: build the world (UGVs, camera) around the outside vehicle at "
        "this MAVLink address (a second link of PX4 / ArduPilot), free-running on its clock",
    )
    parser.add_argument("--autopilot", choices=["builtin", "px4", "ardupilot"], default="builtin",
                        help="builtin: skyherd's autopilot (default); px4 / ardupilot: a real one flies on skyherd's "
                        "physics (PX4 none_iris on TCP 4560+N, ArduPilot --model JSON on UDP 9002+10N)")  # fmt: skip
    parser.add_argument(
        "--follow-system",
        type=int,
        default=0,
        metavar="ID",
        help="with --follow: the followed autopilot's MAVLink system id (0: the first autopilot heard)",
    )
    parser.add_argument(
        "--param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a parameter of the built-in autopilot at start (repeatable), e.g. COM_OF_LOSS_T=3",
    )
    from skyherd.scripts.fault_options import add_fault_arguments

    add_fault_arguments(parser)
    parser.add_argument(
        "--signing-key",
        default=None,
        metavar="FILE",
        help="MAVLink 2 signing key file (32 bytes): sign every frame, reject unsigned ones",
    )
    parser.add_argument(
        "--cut-link",
        action="append",
        default=[],
        metavar="T:D",
        help="cut the companion's MAVLink link both ways at simulation time T [s] for D [s] (repeatable)",
    )
    parser.add_argument(
        "--cut-camera",
        action="append",
        default=[],
        metavar="T:D",
        help="stop the camera's frames at T [s] for D [s] (repeatable)",
    )
    parser.add_argument(
        "--fleet",
        default=None,
        metavar="FILE",
        help="several built-in vehicles in this one process (with --ugvs none): a JSON list of "
        '{"name": "uav0", "instance": N, "seed": S, "home": [LAT, LON, ALT]}; each writes into '
        "<run folder>/<name>/, each in lockstep with its own companion (docs/formation.md)",
    )
    parser.add_argument("--runs-dir", default="runs", help="where the run folder goes")
    parser.add_argument(
        "--run-dir",
        default=None,
        help="write into this existing run folder (used by `skyherd fly`)",
    )


def check_args(argv: list[str]) -> str | None:
    """`skyherd sim`'s own parser and checks on `argv`, starting nothing (no socket, no Zenoh
    session, no file): None if it would start, else the one-line reason. `skyherd fly` calls
    it before it makes its run folder."""
    return check_with("skyherd sim", add_arguments, check, argv)


def check(args) -> tuple:
    """Every check of the arguments that needs nothing started (UsageError, one line): the
    instance and its ports, the world's parameters, the faults, the autopilot's parameters,
    the signing key and the fleet file. Returns (WorldParams, EndpointConfig)."""
    try:
        args.zenoh_port = ports.checked_zenoh_port(args.instance, args.zenoh_port)
    except ValueError as e:
        raise UsageError(str(e)) from None
    for flag, value, low in (("--latency", args.latency, 0.0), ("--camera-hz", args.camera_hz, None),
                             ("--duration", args.duration, None)):  # fmt: skip
        if value is not None and not (
            math.isfinite(value) and (value >= low if low is not None else value > 0)
        ):
            raise UsageError(f"{flag} {value:g}: must be a finite number {'>= 0' if low is not None else '> 0'}")  # fmt: skip
    params, endpoint = build_world(args)
    _faults(args)  # the fault flags, parsed and range-checked
    if not args.follow and args.autopilot == "builtin":
        _check_params(args.airframe, args.param)
    if args.signing_key:
        from skyherd.flight.mavlink.signing import load_key

        try:
            load_key(args.signing_key)
        except ValueError as e:  # SigningError
            raise UsageError(f"--signing-key: {e}") from None
    if args.zenoh_config is not None and not os.path.isfile(args.zenoh_config):
        raise UsageError(
            f"--zenoh-config {args.zenoh_config}: no such file; pass a Zenoh JSON5 file"
        )
    if args.fleet:
        read_fleet(args)
    return params, endpoint


def _check_params(airframe: str, items: list[str]) -> None:
    """--param NAME=VALUE against the built-in autopilot's parameter table (names, numbers,
    ranges), before the autopilot exists; UsageError naming the item."""
    from skyherd.flight.airframes_registry import param_store

    store = param_store(airframe)
    for item in items:
        name, eq, value = item.partition("=")
        if not eq:
            raise UsageError(f"--param {item!r}: expected NAME=VALUE, e.g. COM_OF_LOSS_T=3")
        res = store.check(name.strip(), value.strip())
        if not res.ok:
            raise UsageError(
                f"--param {item}: {res.reason}{_param_hint(store, name.strip(), airframe)}"
            )


def _param_hint(store, name: str, airframe: str) -> str:
    """What to do about an unknown parameter name: the close names, or where the table is."""
    if name in store:
        return ""
    close = store.close_names(name)
    if close:
        return f"; did you mean {' or '.join(close)}?"
    return f"; the built-in {airframe}'s {len(store.names())} parameters: `skyherd sitl` and a ground station list them"


def build_world(args):
    """Check the arguments and build the world (UsageError on bad usage)."""
    from skyherd.flight.lockstep import LockstepParams
    from skyherd.flight.mavlink import EndpointConfig
    from skyherd.task.scenarios import FLOCK, TEAMS
    from skyherd.world.sim import WorldParams

    if args.ugvs not in TEAMS + ("none",):
        raise UsageError(
            f"--ugvs {args.ugvs!r} is not a team: use one of " + ", ".join(TEAMS) + " or none"
        )
    if args.ugvs == FLOCK and (args.follow or args.autopilot != "builtin" or args.fleet):
        raise UsageError(
            "--ugvs flock flees the built-in vehicle only: drop --follow, --autopilot, --fleet"
        )
    if args.ugvs == "none" and (args.follow or args.autopilot != "builtin" or args.cut_camera):
        raise UsageError(
            "--ugvs none is the built-in vehicle alone: drop --follow, --autopilot, --cut-camera"
        )
    args.speedup = default_speedup(args.speedup, args.free_run)
    if not (args.speedup == 0 or args.speedup >= 1):
        raise UsageError("--speedup must be 0 (as fast as possible) or >= 1")
    if args.free_run and args.speedup == 0:
        raise UsageError(
            "--free-run needs a pacer: give --speedup >= 1 (a free-running companion cannot keep up with 0)"
        )
    try:
        params = WorldParams(
            airframe=args.airframe, instance=args.instance, seed=args.seed, scenario=args.ugvs,
            camera_hz=args.camera_hz, ugv_start=args.ugv_start, lockstep=not args.free_run,
            lockstep_params=LockstepParams(latency_s=args.latency), speedup=args.speedup,
            link_cuts=_windows(args.cut_link, "--cut-link"), camera_losses=_windows(args.cut_camera, "--cut-camera"),
            home=_home(args.home), camera="roi" if args.airframe == "fixedwing" else "down",
        )  # fmt: skip
        endpoint = EndpointConfig(instance=args.instance, bind_host=args.bind, remote_host=args.remote,
                                  signing_key=args.signing_key)  # fmt: skip
    except ValueError as e:
        raise UsageError(str(e)) from None
    return params, endpoint


def open_zenoh(port: int, config_file: str | None):
    from skyherd.perception.transport import ZenohParams, open_session, publisher_params

    p = ZenohParams(config_file=config_file) if config_file else publisher_params(port)
    try:
        return open_session(p)
    except ValueError as e:
        if config_file is None and "in use" in str(e):
            raise UsageError(f"Zenoh port {port} on 127.0.0.1 is taken (another simulator, or "
                             "another program, listens there): pick another --instance or "
                             "--zenoh-port") from None  # fmt: skip
        raise UsageError(f"{e}; check --zenoh-port / --zenoh-config") from None


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from skyherd.world.sim import World

    params, endpoint = check(args)
    fleet = read_fleet(args) if args.fleet else None
    if args.run_dir is not None:
        run_dir = Path(args.run_dir)
        if not run_dir.is_dir():
            raise UsageError(f"--run-dir {run_dir} is not a folder")
    else:
        folder = RunFolder("sim", root=args.runs_dir)
        folder.write_config({"args": args_dict(args), "world": params})
        run_dir = folder.path
    if fleet is not None:
        return run_fleet(args, params, endpoint, fleet, run_dir)
    session = (
        _NoSession() if args.ugvs == "none" else open_zenoh(args.zenoh_port, args.zenoh_config)
    )
    try:
        if args.autopilot != "builtin":  # a real autopilot on our physics (hil/ bridges)
            from skyherd.hil.bridge_select import make_bridge
            from skyherd.world.bridged import BridgedWorld

            bridge = make_bridge(
                args.autopilot, args.airframe, args.instance, args.seed, speedup=args.speedup
            )
            world = BridgedWorld(bridge, params, session=session, run_dir=run_dir,
                                 key=_frame_key(args))  # fmt: skip
        elif args.follow:
            world = _follow(args, params, session, run_dir)
        else:
            world = World(
                params,
                session=session if args.ugvs != "none" else None,
                run_dir=run_dir,
                endpoint_config=endpoint,
                faults=_faults(args),
            )

    except ValueError as e:  # flight.mavlink.signing.SigningError: a bad key file
        session.close()
        raise UsageError(f"--signing-key: {e}") from None
    except OSError as e:
        session.close()
        raise UsageError(f"{e}; is another vehicle using instance {args.instance}?") from None
    if not args.follow and args.autopilot == "builtin":
        _set_params(world, args.param, session)
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: world.stop())
    signal.signal(signal.SIGUSR1, lambda *_: _companion_signal([world]))
    mode = "free-running" if args.free_run else f"lockstep (latency {args.latency:g} s)"
    if args.autopilot != "builtin":
        mode = f"{args.autopilot} on skyherd's physics (its own lockstep)"
    say(
        f"skyherd sim: instance {args.instance}, {mode}, speed-up {args.speedup:g}; run folder {run_dir}"
    )
    try:
        stats = world.run(args.duration)
    except Exception as e:  # noqa: BLE001 - say what stopped the world, then close its sockets
        say(f"skyherd sim: stopped: {type(e).__name__}: {e}")
        return 1
    finally:
        world.close()
        session.close()
    say(json.dumps(stats))
    _if_parent_died(args, run_dir)
    return 0


COMPANION_GONE = "SIGUSR1: the companion is gone (it exited)"
"""Why the simulator steps on alone (world.sim.World.companion_gone): `skyherd fly` sends
SIGUSR1 once its companion has exited."""
FLY_DIED = "SIGUSR1: `skyherd fly` died (its parent-death signal)"
"""SIGUSR1 is also the simulator's parent-death signal: then the companion is handing over
(world.sim.World.parent_died)."""


def _companion_signal(worlds) -> None:
    """SIGUSR1: from `skyherd fly` once the companion exited, or the kernel's parent-death
    signal when `skyherd fly` died (the companion got its own and is handing over)."""
    died = _parent_gone()
    for w in worlds:
        if died and hasattr(w, "parent_died"):
            w.parent_died(FLY_DIED)
        elif hasattr(w, "companion_gone"):
            w.companion_gone(FLY_DIED if died else COMPANION_GONE)
        else:
            w.stop()  # a bridged world: nothing flies alone here


PARENT = os.getppid()  # the process that started this one (`skyherd fly`, a shell)


def _if_parent_died(args, run_dir, vehicles: list[str] | None = None) -> None:
    """Under `skyherd fly` (--run-dir) whose process died (kill -9): the simulator, the last
    child to end, says how the flight ended in summary.md."""
    if args.run_dir is not None and _parent_gone():
        from skyherd.scripts.waysout import parent_died

        parent_died(run_dir, vehicles)


def _parent_gone() -> bool:
    """This process's parent has died (or is dying: its main thread a zombie while its other
    threads end, and this process not yet handed to another parent)."""
    if os.getppid() != PARENT:
        return True
    try:
        with open(f"/proc/{PARENT}/stat") as f:
            state = f.read().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return True
    return state in ("Z", "X")


def say(text: str) -> None:
    """A line on stderr (sim.log in a run folder), never raising: a full disk or a read-only
    folder must not stop the vehicle."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def read_fleet(args) -> list:
    """The `--fleet` file (world.fleet), checked with the options it flies with (UsageError)."""
    from skyherd.world.fleet import read_fleet as read_file

    if args.ugvs != "none":
        raise UsageError("--fleet flies built-in vehicles alone: add --ugvs none")
    if (
        args.follow
        or args.autopilot != "builtin"
        or args.airframe != "quadrotor"
        or args.param
        or args.cut_link
    ):
        raise UsageError("--fleet: built-in quadrotors only; drop --follow, --autopilot, --airframe, "
                         "--param, --cut-link (or run one `skyherd sim` per vehicle)")  # fmt: skip
    try:
        return read_file(args.fleet)
    except ValueError as e:
        raise UsageError(str(e)) from None


def run_fleet(args, params, endpoint, fleet: list, run_dir) -> int:
    """Several built-in vehicles in this process (world.fleet): one step of each in turn, each
    in lockstep with its companion (world.sim.run_worlds); each writes into run_dir/<name>/."""
    from skyherd.flight.clock import Pacer
    from skyherd.world.fleet import open_fleet
    from skyherd.world.sim import run_worlds

    try:
        worlds = open_fleet(params, endpoint, fleet, run_dir, lambda seed: _faults(args, seed))
    except ValueError as e:
        raise UsageError(str(e)) from None
    stop = lambda *_: [w.stop() for w in worlds]  # noqa: E731
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, stop)
    signal.signal(signal.SIGUSR1, lambda *_: _companion_signal(worlds))
    names = ", ".join(f"{v.name} (instance {v.instance})" for v in fleet)
    say(f"skyherd sim: fleet of {len(fleet)}: {names}; lockstep (latency {args.latency:g} s), "
        f"speed-up {args.speedup:g}; run folder {run_dir}")  # fmt: skip
    try:
        stats = run_worlds(worlds, Pacer(params.speedup), args.duration)
    except Exception as e:  # noqa: BLE001 - say what stopped the world, then close its sockets
        say(f"skyherd sim: stopped: {type(e).__name__}: {e}")
        return 1
    finally:
        for w in worlds:
            w.close()
    for v, st in zip(fleet, stats):
        say(f"{v.name} {json.dumps(st)}")
    _if_parent_died(args, run_dir, [v.name for v in fleet])
    return 0


def _follow(args, params, session, run_dir):
    """The world around an outside vehicle (world/follow.py)."""
    from skyherd.hil.link import LinkError, MavlinkLink, link_address
    from skyherd.world.follow import FollowWorld

    try:
        link_address(args.follow)
        # ArduPilot SITL opens SERIAL1 only once the companion is on SERIAL0: retry 60 s
        link = MavlinkLink.open(args.follow, connect_wait_s=60.0, source_system=255,
                                source_component=190, signing_key=args.signing_key)  # fmt: skip
    except (ValueError, LinkError) as e:
        session.close()
        raise UsageError(f"--follow: {e}") from None
    return FollowWorld(link, params, session=session, run_dir=run_dir, system_id=args.follow_system,
                       key=_frame_key(args))  # fmt: skip


def _frame_key(args) -> bytes | None:
    """The flight key for the camera frames and UGV states (--signing-key), or None."""
    from skyherd.flight.mavlink.signing import load_key

    return load_key(args.signing_key) if args.signing_key else None


def _set_params(world, items: list[str], session) -> None:
    for item in items:
        name, _, value = item.partition("=")
        try:
            res = world.autopilot.set_param(name.strip(), float(value))
        except ValueError:
            res = None
        if res is None or not res.ok:
            world.close()
            session.close()
            why = res.reason if res is not None else f"{value!r} is not a number"
            raise UsageError(f"--param {item}: {why}")


class _NoSession:
    """The vehicle alone publishes nothing: no Zenoh session to open or close."""

    def close(self) -> None:
        pass


def _home(text: str | None) -> tuple[float, float, float] | None:
    """`LAT,LON,ALT` → (deg, deg, m); UsageError on anything else."""
    if text is None:
        return None
    try:
        lat, lon, alt = (float(x) for x in text.split(","))
    except ValueError:
        raise UsageError(
            f"--home {text!r}: expected LAT,LON,ALT, e.g. 47.397742,8.545594,488"
        ) from None
    if not (-90 <= lat <= 90 and -180 <= lon <= 180 and -500 <= alt <= 9000):
        raise UsageError(f"--home {text!r}: latitude, longitude or altitude out of range")
    return lat, lon, alt


def _faults(args, seed: int | None = None):
    """The fault plan of --wind/--gust/--noise/--fault (None: calm air, perfect state)."""
    from skyherd.scripts.fault_options import plan_from_args

    if not (args.wind or args.gust or args.noise or args.fault):
        return None
    try:
        return plan_from_args(args, seed=args.seed if seed is None else seed)
    except ValueError as e:
        raise UsageError(str(e)) from None


def _windows(items: list[str], flag: str) -> tuple[tuple[float, float], ...]:
    """`T:D` strings → ((start, duration), ...) [s]; UsageError naming the flag."""
    out = []
    for item in items:
        t, _, d = item.partition(":")
        try:
            w = (float(t), float(d))
        except ValueError:
            raise UsageError(f"{flag} {item!r}: expected T:D in seconds, e.g. 30:3") from None
        if not (math.isfinite(w[0]) and math.isfinite(w[1]) and w[0] >= 0 and w[1] > 0):
            raise UsageError(f"{flag} {item!r}: T must be >= 0 and D > 0")
        out.append(w)
    return tuple(out)
