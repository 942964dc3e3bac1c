"""`skyherd companion --connect ADDRESS`: the onboard computer.

MAVLink client of the autopilot (component 191); camera frames from Zenoh; detector → φ(s) →
pilot (learned policy, PID follower, or the square's waypoints) → safety net → setpoints. It
owns no physics and no world. Against `skyherd sim` it ticks in lockstep on the vehicle's
marks; `--free-run` ticks on the autopilot's own clock (a real autopilot).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import errno
import json
import math
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np

from skyherd.runio import JsonlWriter, RunFolder, args_dict, cut_records, ports, try_write_text
from skyherd.scripts.cli import UsageError, check_with

SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""End the flight by handing the vehicles to their autopilots (mission.handover); a second one
ends the companion at once."""
PARENT_DIED = signal.SIGUSR1
"""The companion's parent-death signal under `skyherd fly` (scripts.launch): hand over as
above. The kernel sends it once per thread of the dying parent (each thread that exits hands
its children to the next and signals them again), spread over as long as the dying threads
wait for a CPU: a repeat never counts as a second signal, and one after the flight's loop is
ignored (its default would end the companion before companion.json is written)."""


@contextlib.contextmanager
def stop_on_signals(stop):
    """SIGINT, SIGTERM and SIGHUP set `stop` (a second one, or one before the flight, raises
    runio.Interrupted) while the block runs, and so does PARENT_DIED (never a second); the
    previous handlers afterwards, except PARENT_DIED's: ignored from then on (the loop is
    over, the records are still to be written)."""

    def on_signal(signum, _frame) -> None:
        stop.request(signum, again_ends=signum != PARENT_DIED)

    stop.waiting = True  # until the loop takes over (mission.companion): nothing flies yet
    old = {sig: signal.signal(sig, on_signal) for sig in SIGNALS}
    signal.signal(PARENT_DIED, on_signal)
    try:
        yield stop
    finally:
        signal.signal(PARENT_DIED, signal.SIG_IGN)
        for sig, h in old.items():
            signal.signal(sig, h)


def _signal_name(x) -> str:
    """The signal of an Interrupted or a StopRequest by name (a bare Ctrl-C's is SIGINT; the
    parent-death signal says so)."""
    signum = getattr(x, "signum", None)
    name = signal.Signals(signum).name if signum else "SIGINT"
    return name + (": its parent died" if signum == PARENT_DIED else "")


def _interrupt_rc(stop) -> int:
    return 128 + (stop.signum or signal.SIGINT)


def _say(text: str) -> None:
    """A line on stderr that never raises (stderr may be a file on a full disk)."""
    try:
        print(text, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def _tlog_cut(link) -> list[dict]:
    err = link.tlog_error
    return [{"file": "telemetry.tlog", "error": err, "dropped": None}] if err else []


def add_arguments(
    parser,
    standalone: bool = True,
    missions: tuple[str, ...] = ("groundair", "square", "formation", "orbit", "shepherd"),
) -> None:
    if standalone:
        parser.add_argument(
            "--connect",
            metavar="ADDRESS",
            default=None,
            help=f"the autopilot's MAVLink address (pymavlink form; default {ports.COMPANION_ADDRESS_HELP})",
        )
        parser.add_argument(
            "--instance",
            type=int,
            default=0,
            help=f"vehicle instance N in [0, {ports.MAX_INSTANCE}] (system id 1+N, default "
            f"addresses: MAVLink {ports.COMPANION_ADDRESS_HELP}, Zenoh {ports.ZENOH_ADDRESS_HELP})",
        )
        parser.add_argument(
            "--free-run",
            action="store_true",
            help="tick on the autopilot's clock instead of the simulator's marks (a real autopilot)",
        )
        parser.add_argument(
            "--zenoh-connect",
            default=None,
            metavar="ADDRESS",
            help="where the camera frames are published (tcp:HOST:PORT; default: "
            f"{ports.ZENOH_ADDRESS_HELP} for --instance N)",
        )
        parser.add_argument(
            "--zenoh-config",
            default=None,
            metavar="FILE",
            help="a Zenoh JSON5 configuration instead",
        )
        parser.add_argument(
            "--signing-key",
            default=None,
            metavar="FILE",
            help="MAVLink 2 signing key file (32 bytes) shared with the autopilot",
        )
        parser.add_argument(
            "--orbit-team",
            default="lateral",
            metavar="SCENARIO",
            help="--mission orbit: the UGV team's scenario the companion is briefed with (its start, speed, spread)",
        )
        parser.add_argument(
            "--orbit-seed",
            type=int,
            default=0,
            help="--mission orbit: the team's seed (the briefing)",
        )
        parser.add_argument(
            "--orbit-no-land",
            action="store_true",
            help="--mission orbit: end in the orbit, no landing",
        )
        parser.add_argument(
            "--plan",
            default=None,
            metavar="FILE",
            help="--mission formation: the lock-step grid plan (plan.json / plan_K<K>.json); "
            "vehicle k is instance N+k, its home on its start cell",
        )
        parser.add_argument(
            "--cell-m", type=float, default=2.0, help="--mission formation: grid cell size [m]"
        )
        parser.add_argument("--runs-dir", default="runs", help="where the run folder goes")
        parser.add_argument(
            "--run-dir",
            default=None,
            help="write into this existing run folder (used by `skyherd fly`)",
        )
        parser.add_argument(
            "--wait-go",
            action="store_true",
            help="set up, then wait for a line on standard input before the first message to the "
            "vehicle (its clock starts on it): how `skyherd fly` starts the flight once its "
            "recorder listens",
        )
    parser.add_argument(
        "--mission", choices=list(missions), default="groundair",
        help="groundair: keep the UGVs in view behind the safety net; square: fly a square"
        + ("; formation: K vehicles fly the SQL-SIE plan to their targets" if "formation" in missions else "")
        + ("; orbit: a fixed-wing orbits the team, camera on a pointed gimbal" if "orbit" in missions else "")
        + ("; shepherd: herd the UGV flock (--ugvs flock) into the goal region (docs/shepherding.md)"
           if "shepherd" in missions else ""),
    )  # fmt: skip
    if "shepherd" in missions:
        parser.add_argument("--shepherd-selector", choices=["learned", "strombom"], default="learned",
                            help="--mission shepherd: the high-level selector between collect and drive: learned "
                            "(policy/shepherd/selector.json, fitted to Strömbom's demonstrations) or strombom "
                            "(the hand-written rule)")  # fmt: skip
    parser.add_argument(
        "--pilot",
        type=pilot_choice,
        default="policy",
        help="groundair pilot: policy (the learned one), pid (the classic follower on φ(s)), or "
        "drill:NAME, a named drill's adversarial AI flown by the same mission, e.g. "
        "drill:lateral-fence with --envelope safety/envelopes/quadrotor_field.toml",
    )
    parser.add_argument("--lost-ugv-search", action="store_true",
                        help="groundair: when a UGV leaves the view, search for it (dead reckoning from its last "
                        "sighting, climbing toward the ceiling, expanding square: mission/search.py) instead of "
                        "leaving it to the pilot")  # fmt: skip
    parser.add_argument(
        "--policy",
        default=None,
        metavar="FILE",
        help="policy file: discrete (skyherd train ab / irl / educate) or the deep continuous "
        "ABS-DL policy (skyherd train abs-dl, e.g. policy/models/groundair_absdl.npz) "
        "(default: the discrete AB policy the repository keeps)",
    )
    parser.add_argument(
        "--envelope", default=None, metavar="FILE", help="constraint-set TOML of the safety net"
    )
    parser.add_argument(
        "--altitude",
        type=float,
        default=None,
        metavar="M",
        help="take-off altitude above home [m] (default: 20; `fly` frames the team)",
    )
    parser.add_argument(
        "--duration", type=float, default=60.0, metavar="S", help="flight behind the safety net [s]"
    )
    parser.add_argument("--side", type=float, default=40.0, metavar="M", help="square side [m]")
    parser.add_argument(
        "--no-camera",
        action="store_true",
        help="fly without camera frames (square, or no simulator)",
    )
    parser.add_argument(
        "--setup-signing",
        action="store_true",
        help="an outside autopilot: first send it the --signing-key (SETUP_SIGNING) until it "
        "answers signed, then fly signed. ArduPilot accepts unsigned messages on SERIAL0 (TCP "
        "5760+10N in SITL) whatever the key: connect to SERIAL1/2 for a protected link "
        "(docs/mavlink.md)",
    )
    parser.add_argument(
        "--configure-autopilot",
        action="store_true",
        help="before the take-off, set the autopilot's parameters the safety envelope requires "
        "(e.g. PX4 COM_OF_LOSS_T, ArduCopter GUID_TIMEOUT), read each back and record the change "
        "(companion.json, summary.md); nothing is restored afterwards. Default: refuse to take "
        "off on a mismatch, naming the parameter and the value to set",
    )


def check_args(argv: list[str]) -> str | None:
    """`skyherd companion`'s own parser and checks on `argv`, starting nothing (no link, no
    Zenoh session, no file): None if it would start, else the one-line reason. `skyherd fly`
    calls it before it makes its run folder."""
    return check_with("skyherd companion", add_arguments, check, argv)


def check(args) -> str:
    """Every check of the arguments that needs nothing started (UsageError, one line); fills
    the instance's default addresses in. Returns the autopilot's MAVLink address."""
    from skyherd.hil.link import link_address

    try:
        ports.check_instance(args.instance)
    except ValueError as e:
        raise UsageError(str(e)) from None
    address = args.connect or ports.companion_address(args.instance)
    try:
        link_address(address)
    except ValueError as e:
        raise UsageError(str(e)) from None
    if args.zenoh_connect is None:
        args.zenoh_connect = ports.zenoh_address(args.instance)
    zenoh_endpoint(args.zenoh_connect)
    if not 0 < args.duration <= 36000:  # NaN fails too
        raise UsageError("--duration must be in (0, 36000] s")
    if args.altitude is not None and not 0 < args.altitude <= 120:
        raise UsageError(f"--altitude {args.altitude:g}: must be in (0, 120] m above home")
    if not 0 < args.side <= 500:
        raise UsageError(f"--side {args.side:g}: must be in (0, 500] m")
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
        from skyherd.flight.mavlink.signing import load_key

        try:
            load_key(args.signing_key)
        except ValueError as e:  # SigningError
            raise UsageError(f"--signing-key: {e}") from None
    if args.zenoh_config is not None and not Path(args.zenoh_config).is_file():
        raise UsageError(
            f"--zenoh-config {args.zenoh_config}: no such file; pass a Zenoh JSON5 file"
        )
    return address


def mission_choice(args):
    """The mission the command line chose (mission.build.MissionChoice); an option another
    command's parser lacks keeps its default."""
    from skyherd.mission.build import MissionChoice

    d = MissionChoice()
    return MissionChoice(
        mission=args.mission, altitude_m=args.altitude, duration_s=args.duration,
        side_m=args.side, envelope=args.envelope, pilot=args.pilot, policy=args.policy,
        lost_ugv_search=getattr(args, "lost_ugv_search", d.lost_ugv_search),
        configure_autopilot=getattr(args, "configure_autopilot", d.configure_autopilot),
        shepherd_selector=getattr(args, "shepherd_selector", d.shepherd_selector),
        orbit_team=getattr(args, "orbit_team", d.orbit_team),
        orbit_seed=getattr(args, "orbit_seed", d.orbit_seed),
        orbit_no_land=getattr(args, "orbit_no_land", d.orbit_no_land),
    )  # fmt: skip


def pilot_choice(value: str) -> str:
    """--pilot: policy, pid, or drill:NAME (a named drill of safety.drills; - for a space)."""
    if value in ("policy", "pid") or value.startswith("drill:"):
        return value
    raise argparse.ArgumentTypeError(f"{value!r}: use policy, pid or drill:NAME")


def zenoh_endpoint(address: str) -> str:
    """pymavlink-style `tcp:HOST:PORT` → Zenoh's `tcp/HOST:PORT` (one address syntax)."""
    kind, _, rest = address.partition(":")
    host, _, port = rest.rpartition(":")
    if kind not in ("tcp", "udp") or not host or not port.isdigit():
        raise UsageError(f"cannot parse Zenoh address {address!r}; expected tcp:HOST:PORT")
    return f"{kind}/{host}:{port}"


def open_frames(args, vehicle: str = "uav0"):
    from skyherd.mission.companion import FrameInbox
    from skyherd.perception.transport import FrameSubscriber, ZenohParams, subscriber_params

    # a client of the simulator's peer: Zenoh routes between its clients (a recorder, a viewer)
    p = ZenohParams(config_file=args.zenoh_config) if args.zenoh_config else dataclasses.replace(
        subscriber_params(zenoh_endpoint(args.zenoh_connect)), mode="client")  # fmt: skip
    try:
        session = open_client(p)
    except ValueError as e:
        raise UsageError(f"{e}; check --zenoh-connect / --zenoh-config") from None
    key = None
    if getattr(args, "signing_key", None):  # the flight's key authenticates the frames too
        from skyherd.flight.mavlink.signing import SigningError, load_key

        try:
            key = load_key(args.signing_key)
        except SigningError as e:
            session.close()
            raise UsageError(f"--signing-key: {e}") from None
    return session, FrameInbox(FrameSubscriber(session, vehicle, key=key))


GO_PATIENCE_S = 120.0
"""--wait-go: how long [s of wall time] the companion waits for its go."""


def wait_go(args, patience_s: float = GO_PATIENCE_S) -> None:
    """--wait-go: block until a line arrives on standard input (EOFError when it is closed
    first, TimeoutError when nothing comes within `patience_s` of wall time)."""
    import select

    if not args.wait_go:
        return
    ready, _, _ = select.select([sys.stdin], [], [], patience_s)
    if not ready:
        raise TimeoutError(f"--wait-go: no go on standard input within {patience_s:.0f} s")
    if not sys.stdin.readline():
        raise EOFError("--wait-go: standard input closed before the go "
                       "(did the `skyherd fly` that started this companion stop?)")  # fmt: skip


class GaveUp(Exception):
    """open_client stopped waiting: its `give_up()` said so (the simulator ended, a signal)."""


def open_client(p, patience_s: float = 60.0, give_up=None):
    """A Zenoh session that connects to a simulator which may not listen yet (a client's open
    fails at once when nothing answers): retried every 0.05 s of wall time for `patience_s`
    (a refused open costs about a millisecond), until `give_up()` is True (GaveUp then)."""
    import time

    from skyherd.perception.transport import open_session

    deadline = time.monotonic() + patience_s
    while True:
        try:
            return open_session(p)
        except ValueError:
            if time.monotonic() > deadline:
                raise
            if give_up is not None and give_up():
                raise GaveUp() from None
            time.sleep(0.05)


def run(args: argparse.Namespace) -> int:
    from skyherd.hil.link import LinkError, MavlinkLink
    from skyherd.mission.companion import CompanionParams
    from skyherd.mission.companion import run as run_companion
    from skyherd.mission.vehicle import VehicleLink
    from skyherd.runio.constants import COMPANION_COMPONENT

    address = check(args)
    use_camera = args.mission in ("groundair", "shepherd") and not args.no_camera
    if args.mission == "orbit":
        use_camera = not args.no_camera
    if args.run_dir is not None:
        run_dir = Path(args.run_dir)
        if not run_dir.is_dir():
            raise UsageError(f"--run-dir {run_dir} is not a folder")
    else:
        run_dir = None
    folder = None
    if run_dir is None:
        folder = RunFolder("companion", root=args.runs_dir)
        run_dir = folder.path
    if args.mission == "formation":
        return _run_formation(args, run_dir, folder)
    from skyherd.mission.build import attach_flock, build_mission

    try:
        mission, plan = build_mission(mission_choice(args), run_dir, _say)
    except ValueError as e:
        if folder is not None:  # no run folder for a usage error
            shutil.rmtree(run_dir, ignore_errors=True)
        raise UsageError(str(e)) from None
    if folder is not None:
        folder.write_config({"args": args_dict(args), "plan": plan, "address": address})
    session = frames = None
    if use_camera:
        session, frames = open_frames(args)
        _publish_live(session, mission, key=frames.sub.key)
        if args.mission == "shepherd":
            attach_flock(session, mission, key=frames.sub.key)
        from skyherd.mission.companion import LoggedFrames
        from skyherd.runio import CsvWriter

        frames = LoggedFrames(frames, CsvWriter(run_dir / "frames.csv", LoggedFrames.COLUMNS))
    mission.authority.log = JsonlWriter(run_dir / "modes.jsonl")  # every (mode, armed) change
    try:
        link = MavlinkLink.open(address, source_system=1 + args.instance, source_component=COMPANION_COMPONENT,
                                tlog=run_dir / "telemetry.tlog", signing_key=args.signing_key)  # fmt: skip
    except (LinkError, ValueError) as e:  # ValueError: flight.mavlink.signing.SigningError
        if session is not None:
            session.close()
        raise UsageError(link_error_text(e, address, args.instance)) from None
    if getattr(args, "setup_signing", False):
        try:
            sent = link.provision_signing()
        except LinkError as e:
            link.close()
            if session is not None:
                session.close()
            raise UsageError(str(e)) from None
        _say(f"skyherd companion: --setup-signing: the vehicle signs with our key "
             f"({sent} SETUP_SIGNING sent)")  # fmt: skip
    v = VehicleLink(link)
    params = CompanionParams(lockstep=not args.free_run)
    print(f"skyherd companion: {args.mission} via {address}, "
          f"{'free-running' if args.free_run else 'lockstep'}; run folder {run_dir}", file=sys.stderr, flush=True)  # fmt: skip
    error = ""
    stats = None
    interrupted = False
    from tqdm import tqdm

    bar = tqdm(total=None, desc="connect", file=sys.stderr, leave=True, mininterval=0.5,
               bar_format="{desc}: {n} ticks, {elapsed} wall {postfix}")  # fmt: skip
    shown = {"phase": "connect"}

    def on_tick(veh):
        mission.write_track(veh)
        mission.authority.record(veh)  # the changes outside the net's loop (take-off, landing)
        if shown["phase"] != mission.phase:
            shown["phase"] = mission.phase
            bar.set_description_str(mission.phase, refresh=False)
        bar.set_postfix_str(f"t = {veh.t:.1f} s", refresh=False)
        bar.update()

    from skyherd.mission.handover import StopRequest

    stop = StopRequest()
    writers = [mission.rec.decisions, mission.rec.track, getattr(mission.net, "events", None)]
    try:
        with stop_on_signals(stop):
            wait_go(args)
            stats = run_companion(v, mission, mission.run(v), frames, params, on_tick, stop)
    except Exception as e:  # noqa: BLE001 - the flight ends; say why, keep what was recorded
        error = f"{type(e).__name__}: {e}" if not str(e).startswith(type(e).__name__) else str(e)
        mission.outcome, mission.reason = "aborted", str(e)
    except KeyboardInterrupt as e:
        error, interrupted = f"interrupted ({_signal_name(e)})", True
        mission.outcome, mission.reason = "interrupted", error
    finally:
        bar.close()
        mission.write_track(v)
        link.close()
        sub = getattr(getattr(frames, "source", None), "sub", None)
        if sub is not None:  # its callbacks end before the session does
            sub.close()
        if session is not None:
            session.close()
    if stats is not None and stats.handover is not None:  # a signal: handed over, then ended
        error, interrupted = (
            f"interrupted ({_signal_name(stop)}): {'; '.join(stats.handover)}",
            True,
        )
        mission.outcome, mission.reason = "interrupted", error
    cut = cut_records(writers) + _tlog_cut(link)
    mavlink = {"signed": link.signing is not None and link.signing.enabled,
               "rejected": link.rejected_packets}  # fmt: skip
    _write_outcome(run_dir, mission, stats, frames, cut, mavlink)
    if error:
        _say(f"skyherd companion: {'' if interrupted else 'aborted: '}{error}")
    rc = 0 if mission.outcome == "completed" else (_interrupt_rc(stop) if interrupted else 1)
    if folder is not None:  # on its own (not under `skyherd fly`): its own summary and plots
        from skyherd.report.fly import report

        report(run_dir, args, rc, error)
    return rc


def link_error_text(e: Exception, address: str, instance: int) -> str:
    """Why the autopilot's link did not open, in one line with the next step."""
    cause = e.__cause__
    if isinstance(cause, ConnectionRefusedError):
        return (f"nothing is listening at {address} (connection refused): start the autopilot "
                "first, or check --connect")  # fmt: skip
    if isinstance(cause, TimeoutError):
        return f"no answer from {address} (timed out): is the autopilot there? check --connect"
    if isinstance(cause, OSError) and cause.errno == errno.EADDRINUSE:
        return (f"{address}: the port is taken (another companion of instance {instance}, or a "
                "ground station?): stop it, or pick another --instance / --connect")  # fmt: skip
    if isinstance(e, ValueError):
        return f"--signing-key: {e}"
    return f"{e}; check --connect"


def _tick_stats(stats) -> dict:
    """companion.json's loop figures: ticks, decision latency (wall) and CPU time."""
    lat = np.array(stats.decide_wall_s if stats and stats.decide_wall_s else [np.nan])
    some = bool(np.isfinite(lat).any())
    return {
        "ticks": stats.ticks if stats else 0,
        "decide_wall_p50_s": float(np.nanpercentile(lat, 50)) if some else None,
        "decide_wall_p95_s": float(np.nanpercentile(lat, 95)) if some else None,
        "cpu_s": time.process_time(),  # the companion's CPU time since it started [s]
        "cpu_flight_s": stats.cpu_s if stats else None,  # ... from its first tick on [s]
    }


def _write_outcome(run_dir: Path, mission, stats, frames, cut: list | None = None,
                   mavlink: dict | None = None) -> None:  # fmt: skip
    """companion.json: how the mission ended, its counters, the decision latency, the records
    a full disk or a read-only folder cut (never raises: the ending is still reported)."""
    out = {
        "outcome": mission.outcome,
        "reason": mission.reason,
        "handover": stats.handover if stats is not None else None,
        "records_cut": cut or [],
        "phase": mission.phase,
        "decisions": len(mission.rec.rows),
        **_tick_stats(stats),
        "mode_requests": mission.authority.requests,
        "yielded": mission.authority.yielded,
        "frames": None if mission.perception is None else mission.perception.counts,
        "landing": getattr(mission, "landing_note", "") or "as planned",
        "configured": [c.record() for c in getattr(mission, "configured", [])],
        "authority": {
            "t_start": mission.authority.t_start,
            "t_end": mission.authority.t_last,
            "land": bool(getattr(getattr(mission, "f", mission.plan), "land", True)),
            "end_mode": getattr(mission, "end_mode", ""),  # the profile's end when not landed
        },  # fmt: skip
    }
    if mavlink is not None:  # the link's signing: on or off, frames refused by it
        out["mavlink"] = mavlink
    sub = getattr(getattr(frames, "source", frames), "sub", None)
    if sub is not None:  # the camera link: authenticated or not, frames refused by it
        out["camera_link"] = {"authenticated": sub.key is not None, "refused": sub.stats.refused,
                              "out_of_order": sub.stats.out_of_order,
                              "info_refused": sub.stats.info_refused}  # fmt: skip
    flock = getattr(mission, "flock_sub", None)
    if flock is not None:  # the shepherd's UGV states: authenticated or not, refused
        out["ugv_link"] = {"authenticated": flock.key is not None, "received": flock.received,
                           "refused": flock.refused}  # fmt: skip
    if getattr(mission, "plan", None) is not None and mission.name == "orbit":
        import dataclasses as dc

        out["orbit"] = {"plan": dc.asdict(mission.plan), "briefing": dc.asdict(mission.brief),
                        "t_handover": mission.t_handover, "t_established": mission.t_established,
                        "t_orbit_end": mission.t_orbit_end,
                        "centre_limited": mission.limited, "roi": "DO_SET_ROI_LOCATION"}  # fmt: skip
        from skyherd.runio import CsvWriter

        w = CsvWriter(run_dir / "sight.csv", ["t", "detected", "all_in_view"])
        for t, n, all_in in mission.sight.rows:
            w.write({"t": t, "detected": n, "all_in_view": int(all_in)})
        w.close()
    if mission.net is not None:
        st = mission.net.stats
        out["net"] = {"switches": st.switches, "rejected": st.rejected, "projected": st.projected,
                      "fallback_s": st.fallback_s, "pid_s": st.pid_s}  # fmt: skip
    try_write_text(run_dir / "companion.json", json.dumps(out, indent=2) + "\n")
    if mission.perception is not None and mission.perception.strip:
        from skyherd.perception.detector import write_png

        try:
            write_png(run_dir / "frames.png", mission.perception.strip.sheet())
        except OSError as e:
            _say(f"skyherd companion: frames.png not written ({e.strerror or e})")


def _publish_live(session, mission, vehicle: str = "uav0", key: bytes | None = None) -> None:
    """Decisions on skyherd/<vehicle>/decision and the net's events on .../safety/event, so a
    recorder or a live view in another process sees them (record.ZenohRecorder); with the
    flight's key each carries its MAC (runio.mac)."""
    from skyherd.safety.events import Tee, ZenohEventSink

    mission.rec.live = session.declare_publisher(f"skyherd/{vehicle}/decision")
    mission.rec.live_key = key
    if mission.net is not None:
        mission.net.set_events(Tee(mission.net.events, ZenohEventSink(session, vehicle, key)))


def _run_formation(args, run_dir: Path, folder) -> int:
    """K vehicles (instances N..N+K-1) in lockstep, one link each (mission.formation)."""
    from skyherd.flight.geo import DEFAULT_HOME
    from skyherd.hil.link import LinkError, MavlinkLink
    from skyherd.mission.companion import CompanionParams, run_fleet
    from skyherd.mission.formation import FleetRecord, FormationMission
    from skyherd.mission.formation_plan import (
        TRACK_COLUMNS,
        FormationParams,
        PlanError,
        field_offsets,
        load_plan,
        plan_ne,
        vehicle_homes,
        vehicle_instances,
    )
    from skyherd.mission.vehicle import VehicleLink
    from skyherd.runio import CsvWriter
    from skyherd.runio.constants import COMPANION_COMPONENT

    try:
        K = len(json.loads(Path(args.plan).read_text(encoding="utf-8")))
        plan = load_plan(args.plan, K)
        params = FormationParams(cell_m=args.cell_m)
    except (OSError, ValueError, TypeError) as e:  # PlanError is a ValueError
        if folder is not None:
            shutil.rmtree(run_dir, ignore_errors=True)
        kind = "plan" if not isinstance(e, ValueError) or isinstance(e, PlanError) else "formation"
        raise UsageError(f"{kind}: {e}; pass a plan_K<K>.json from `skyherd train sql`") from None
    homes = vehicle_homes(DEFAULT_HOME, [p[0] for p in plan], params.cell_m)
    if folder is not None:
        folder.write_config({"args": args_dict(args), "formation": params, "homes": homes})
    events = JsonlWriter(run_dir / "events.jsonl")
    record = FleetRecord(JsonlWriter(run_dir / "decisions.jsonl"),
                         CsvWriter(run_dir / "metrics.csv", TRACK_COLUMNS))  # fmt: skip
    mission = FormationMission(plan_ne(plan, params.cell_m), field_offsets(DEFAULT_HOME, homes),
                               params, record, events)  # fmt: skip
    instances = vehicle_instances(args.instance, K)
    links = []
    try:
        for k in range(K):
            inst = instances[k]
            (run_dir / f"uav{k}").mkdir(exist_ok=True)
            links.append(MavlinkLink.open(ports.companion_address(inst), source_system=1 + inst,
                                          source_component=COMPANION_COMPONENT,
                                          tlog=run_dir / f"uav{k}" / "telemetry.tlog",
                                          signing_key=args.signing_key))  # fmt: skip
    except LinkError as e:
        for link in links:
            link.close()
        raise UsageError(
            f"{e}; is another companion using instances {instances[0]}..{instances[-1]}?"
        ) from None
    vs = [VehicleLink(link, target_system=1 + inst) for link, inst in zip(links, instances)]
    print(f"skyherd companion: formation of {K} (instances {', '.join(map(str, instances))}), "
          f"lockstep; run folder {run_dir}", file=sys.stderr, flush=True)  # fmt: skip
    from tqdm import tqdm

    bar = tqdm(total=None, desc="connect", file=sys.stderr, leave=True, mininterval=0.5,
               bar_format="{desc}: {n} ticks, {elapsed} wall {postfix}")  # fmt: skip

    def on_tick(vs_):
        mission.write_track(vs_)
        bar.set_description_str(mission.phase, refresh=False)
        bar.set_postfix_str(f"t = {vs_[0].t:.1f} s", refresh=False)
        bar.update()

    from skyherd.mission.handover import StopRequest

    error, stats, interrupted = "", None, False
    stop = StopRequest()
    try:
        with stop_on_signals(stop):
            wait_go(args)
            stats = run_fleet(vs, mission, mission.run(vs), None, CompanionParams(), on_tick, stop)
    except Exception as e:  # noqa: BLE001 - the flight ends; say why, keep what was recorded
        error = str(e) or type(e).__name__
        mission.outcome, mission.reason = "aborted", error
    except KeyboardInterrupt as e:
        error, interrupted = f"interrupted ({_signal_name(e)})", True
        mission.outcome, mission.reason = "interrupted", error
    finally:
        bar.close()
        mission.write_track(vs)
        for link in links:
            link.close()
        for w in (events, record.decisions, record.track):
            w.close()
    if stats is not None and stats.handover is not None:  # a signal: handed over, then ended
        error, interrupted = (
            f"interrupted ({_signal_name(stop)}): {'; '.join(stats.handover)}",
            True,
        )
        mission.outcome, mission.reason = "interrupted", error
    times = {k: None if math.isnan(t) else t for k, t in mission.times.items()}
    out = {"outcome": mission.outcome, "reason": mission.reason, "phase": mission.phase,
           "decisions": record.rows, "vehicles": K, "times": times,
           "yielded": {f"uav{k}": w for k, w in mission.yielded.items()},
           "mode_requests": sum(a.requests for a in mission.authority),
           "net": mission.net_counts(), **_tick_stats(stats),
           "handover": stats.handover if stats is not None else None,
           "records_cut": cut_records([events, record.decisions, record.track]),
           "mavlink": {"signed": all(link.signing is not None and link.signing.enabled for link in links),
                       "rejected": {f"uav{k}": link.rejected_packets for k, link in enumerate(links)}}}  # fmt: skip
    try_write_text(run_dir / "companion.json", json.dumps(out, indent=2) + "\n")
    if error:
        _say(f"skyherd companion: {'' if interrupted else 'aborted: '}{error}")
    rc = 0 if mission.outcome == "completed" else (_interrupt_rc(stop) if interrupted else 1)
    if folder is not None:
        from skyherd.report.formation import formation_report

        formation_report(run_dir, rc, error)
    return rc
