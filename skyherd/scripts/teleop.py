"""`skyherd teleop`: record a demonstration of a GroundAir scenario from the keyboard.

Keys (raw terminal, no Enter needed):
    w north   s south   d east   a west   r climb   f descend   space hover   q quit (save)
Only the manoeuvres of the chosen scenario are accepted (climb: r; descend: f; lateral: w a s d);
any other key means hover. With --step-s S > 0 the task runs in real time: each S seconds the
last key pressed is the action (none → hover). With --step-s 0 it waits for one key per step
(turn-based; this is how the tests drive it through a pseudo-terminal).

Joystick or ground station: `--mavlink ADDRESS` (e.g. udpin:127.0.0.1:14560, where QGroundControl
or a joystick bridge sends MAVLink MANUAL_CONTROL) replaces the keyboard. The stick with the largest
deflection beyond a dead band picks the action (`manual_control_action`): x forward → north/south,
y right → east/west, z thrust above/below its 500 centre → climb/descend; button 1 quits. With
--step-s 0 every MANUAL_CONTROL message is one step; otherwise the newest message of each step
counts and a stick silent for more than 1 s means hover.

`--mavlink ADDRESS --continuous` keeps the stick proportional (`manual_control_velocity`): x/1000
of the horizontal speed limit north, y/1000 of it east, thrust (z − 500)/500 of the climb limit
above the centre and of the descent limit below it, the limits being ABS-DL's continuous ones
(policy.absdl.env.velocity_limits); only the scenario's manoeuvres pass. The episode is flown in
policy.absdl.env.ContinuousGroundAirEnv and saved as skyherd-demo/2 with the commanded velocity
of every step (`vel_ned`), ready for `skyherd train abs-dl --demos FOLDER`.

The run folder (`runs/<time>-teleop/`) gets config.json, summary.md and the demonstration
(`<scenario>.npz`, unless --out says elsewhere).

The view is drawn as text: the camera image scaled to 40×15 characters, 'o' a UGV, '+' the image
centre. The demonstration is saved in the skyherd-demo format (policy.demos) and is ready for
`skyherd train irl|ab --demos FOLDER` (name the files <scenario>.npz).
"""

from __future__ import annotations

import argparse
import os
import select
import sys
import termios
import time
import tty
from pathlib import Path

from skyherd.runio import RunFolder
from skyherd.scripts.cli import UsageError

KEYS = {"w": 1, "s": 2, "d": 3, "a": 4, "r": 5, "f": 6, " ": 0}
STICK_FULL = 1000
"""MANUAL_CONTROL x, y full deflection (−1000..1000); thrust z spans 0..1000."""
THRUST_HOLD = 500
"""MANUAL_CONTROL thrust z at the centre: hold the altitude."""


def manual_control_action(x: int, y: int, z: int, allowed, deadband: int = 300) -> int:
    """MANUAL_CONTROL axes (x, y in −1000..1000; z thrust 0..1000, 500 = hold) → action index."""
    cands = [(x, 1, 2), (y, 3, 4), (z - THRUST_HOLD, 5, 6)]
    defl, pos, neg = max(cands, key=lambda c: abs(c[0]) * (2 if c[1] == 5 else 1))
    scale = 2 if pos == 5 else 1  # thrust spans half the range of the other sticks
    if abs(defl) * scale < deadband:
        return 0
    a = pos if defl > 0 else neg
    return a if a in allowed else 0


def manual_control_velocity(x: int, y: int, z: int, scenario: str, limits):
    """MANUAL_CONTROL axes → (3,) NED velocity [m/s], proportional to the stick.

    north = x/1000 · h, east = y/1000 · h, down = −(z − 500)/500 · up above the thrust centre
    and (500 − z)/500 · down below it, with `limits` (policy.absdl.env.VelocityLimits) h, up,
    down; only the scenario's manoeuvres (policy.absdl.demonstrator.restrict), then clipped to
    the limits (the horizontal speed to its disc)."""
    import numpy as np

    from skyherd.policy.absdl.demonstrator import restrict

    dz = (z - THRUST_HOLD) / THRUST_HOLD
    down = -dz * (limits.up_mps if dz > 0 else limits.down_mps)
    v = np.array([x / STICK_FULL * limits.h_mps, y / STICK_FULL * limits.h_mps, down])
    return limits.clip(restrict(scenario, v))


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--scenario",
        default="lateral",
        choices=("lateral", "climb", "descend", "composite"),
        help="what to demonstrate",
    )
    parser.add_argument("--episodes", type=int, default=1, help="episodes to record")
    parser.add_argument("--seed", type=int, default=0, help="environment seed of the first episode")
    parser.add_argument(
        "--step-s",
        type=float,
        default=0.5,
        help="wall seconds per step; 0 = wait for a key each step",
    )
    parser.add_argument(
        "--episode-s", type=float, default=60.0, help="episode length [s] (sim time)"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=None,
        help="output .npz (default: <scenario>.npz in the run folder, ready for "
        "`skyherd train irl|ab --demos FOLDER`)",
    )
    parser.add_argument(
        "--runs-dir", dest="runs_dir", type=Path, default=Path("runs"),
        help="where run folders go",
    )  # fmt: skip
    parser.add_argument(
        "--mavlink",
        default=None,
        metavar="ADDRESS",
        help="take MANUAL_CONTROL from a joystick/ground station at ADDRESS instead of keys",
    )
    parser.add_argument(
        "--continuous",
        action="store_true",
        help="with --mavlink: record the stick as a continuous velocity (ABS-DL's limits, "
        "skyherd-demo/2) instead of the seven discrete actions",
    )
    parser.add_argument("--no-view", action="store_true", help="do not draw the text view")


def _view(env) -> str:
    W, H = 40, 15
    grid = [[" "] * W for _ in range(H)]
    cam = env.cam
    uv, seen = cam.pixels(env.n, env.e, env.alt, env.formation.positions())
    grid[H // 2][W // 2] = "+"
    for (u, v), s in zip(uv, seen):
        if s:
            grid[min(int(v / cam.H * H), H - 1)][min(int(u / cam.W * W), W - 1)] = "o"
    lines = ["+" + "-" * W + "+"] + ["|" + "".join(r) + "|" for r in grid] + ["+" + "-" * W + "+"]
    return "\r\n".join(lines)


def run(args: argparse.Namespace) -> int:
    if args.episodes < 1 or args.step_s < 0 or args.episode_s <= 0:
        raise UsageError("need --episodes >= 1, --step-s >= 0 and --episode-s > 0")
    if args.continuous and not args.mavlink:
        raise UsageError("--continuous needs --mavlink ADDRESS (keys have no proportional axis)")
    if args.mavlink:
        return _run_mavlink(args)
    fd = sys.stdin.fileno()
    if not os.isatty(fd):
        raise UsageError("teleop needs a terminal on stdin (run it in a terminal, not a pipe)")
    with RunFolder.open("teleop", args, root=args.runs_dir) as run:
        return _run_keyboard(args, run, fd)


def _run_keyboard(args: argparse.Namespace, run, fd: int) -> int:
    from skyherd.policy.demos import ALLOWED_ACTIONS, record
    from skyherd.task.params import ACTION_NAMES, TaskParams

    allowed = ALLOWED_ACTIONS[args.scenario]
    task = TaskParams(episode_s=args.episode_s)
    out = _out_path(args, run)
    old = termios.tcgetattr(fd)
    state = {"t_next": None, "last": 0}

    def read_key(timeout: float | None) -> str | None:
        r, _, _ = select.select([fd], [], [], timeout)
        return os.read(fd, 1).decode(errors="ignore") if r else None

    def act(obs) -> int:
        key = None
        if args.step_s == 0:
            key = read_key(None)
        else:
            now = time.monotonic()
            if state["t_next"] is None:
                state["t_next"] = now + args.step_s
            while (left := state["t_next"] - time.monotonic()) > 0:
                k = read_key(left)
                if k is not None:
                    key = k
            state["t_next"] += args.step_s
        if key == "q" or key == "\x03":
            return -1
        a = KEYS.get((key or " ").lower(), 0)
        return a if a in allowed else 0

    def show(env, obs, a) -> None:
        if args.no_view:
            return
        m = env.episode_metrics()
        sys.stdout.write(
            "\x1b[H\x1b[2J" + _view(env) + "\r\n"
            f"{args.scenario}  t={env.formation.t:5.1f}s  alt={env.alt:5.1f} m  "
            f"action={ACTION_NAMES[a]:8s} in view {int(obs[4] * 3)}/3  "
            f"all-in-view so far {m['all_in_view_frac']:.2f}\r\n"
            "w/s north/south  d/a east/west  r climb  f descend  space hover  q quit\r\n"
        )
        sys.stdout.flush()

    try:
        tty.setcbreak(fd)
        sys.stdout.write(
            f"teleop ready: {args.scenario}, keys w/s/d/a/r/f, space hover, q quit\r\n"
        )
        sys.stdout.flush()
        demo = record(
            args.scenario,
            act,
            args.episodes,
            args.seed,
            "teleop:keyboard",
            {"keys": KEYS, "step_s": args.step_s},
            task=task,
            on_step=show,
        )
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)
    return _save(args, run, demo, out, "keyboard")


def _out_path(args: argparse.Namespace, run) -> Path:
    out = args.out or run.file(f"{args.scenario}.npz")
    out.parent.mkdir(parents=True, exist_ok=True)
    return out


def _save(args: argparse.Namespace, run, demo, out: Path, source: str) -> int:
    """Save the demonstration, say what it holds in summary.md; nothing recorded = failed."""
    from skyherd.runio import file_facts, markdown_table

    if demo.actions.shape[0] == 0:
        print("nothing recorded (quit before the first step)")
        run.fail("nothing recorded (quit before the first step)")
        return 1
    demo.save(out)
    m = demo.meta["episode_metrics"]
    print(f"run folder: {run.path}")
    run.config(demo=file_facts(out), source=source)
    run.describe(out.name, f"the demonstration ({args.scenario}, {source}), skyherd-demo format")
    rows = [[i, x["all_in_view_frac"]] for i, x in enumerate(m)]
    run.summary(
        f"{demo.actions.shape[0]} steps of {args.scenario} from the {source} in {len(m)} "
        f"episode(s), saved to `{out}`.\n\n"
        + markdown_table(["episode", "all-in-view fraction"], rows)
    )
    print(
        f"\nrecorded {demo.actions.shape[0]} steps in {len(m)} episode(s) of {args.scenario} → {out}"
    )
    print(f"all-in-view fraction per episode: {[round(x['all_in_view_frac'], 3) for x in m]}")
    return 0


def _run_mavlink(args: argparse.Namespace) -> int:
    """Record a demonstration from MAVLink MANUAL_CONTROL messages."""
    from skyherd.hil.link import MavlinkLink
    from skyherd.runio import AddressError, mavlink_address

    try:
        address = mavlink_address(args.mavlink)
    except AddressError as e:
        raise UsageError(f"--mavlink {e}") from e
    try:
        link = MavlinkLink.open(address)
    except Exception as e:
        raise UsageError(f"cannot open {args.mavlink}: {e}") from e
    with RunFolder.open("teleop", args, root=args.runs_dir) as run:
        run.closing(link)
        return _run_link(args, run, link)


def _run_link(args: argparse.Namespace, run, link) -> int:
    from skyherd.policy.absdl.env import velocity_limits
    from skyherd.policy.demos import ALLOWED_ACTIONS, record
    from skyherd.task.params import TaskParams

    allowed = ALLOWED_ACTIONS[args.scenario]
    limits = velocity_limits() if args.continuous else None
    task = TaskParams(episode_s=args.episode_s)
    out = _out_path(args, run)
    state = {"last": None, "t_last": -1e9, "t_next": None}
    mode = "continuous" if args.continuous else "discrete"
    print(f"teleop ready: {args.scenario}, MANUAL_CONTROL on {args.mavlink} ({mode})", flush=True)

    def newest():
        """This step's MANUAL_CONTROL message; None = the stick is silent (hover)."""
        if args.step_s == 0:
            while True:
                for m in link.recv(0.5):
                    if m.get_type() == "MANUAL_CONTROL":
                        return m
        if state["t_next"] is None:
            state["t_next"] = time.monotonic() + args.step_s
        while (left := state["t_next"] - time.monotonic()) > 0:
            for m in link.recv(min(left, 0.1)):
                if m.get_type() == "MANUAL_CONTROL":
                    state["last"], state["t_last"] = m, time.monotonic()
        state["t_next"] += args.step_s
        if state["last"] is None or time.monotonic() - state["t_last"] > 1.0:
            return None
        return state["last"]

    def act(obs) -> int:
        m = newest()
        if m is not None and m.buttons & 1:
            return -1
        return 0 if m is None else manual_control_action(m.x, m.y, m.z, allowed)

    def act_velocity(obs):
        m = newest()
        if m is not None and m.buttons & 1:
            return None
        if m is None:
            return (0.0, 0.0, 0.0)
        return manual_control_velocity(m.x, m.y, m.z, args.scenario, limits)

    meta = {"address": args.mavlink, "step_s": args.step_s}
    if args.continuous:
        meta["velocity_limits"] = limits
    try:
        demo = record(
            args.scenario,
            act_velocity if args.continuous else act,
            args.episodes,
            args.seed,
            "mavlink:MANUAL_CONTROL" + (":continuous" if args.continuous else ""),
            meta,
            task=task,
            continuous=args.continuous,
        )
    finally:
        link.close()
    return _save(args, run, demo, out, f"MAVLink MANUAL_CONTROL, {mode}")
