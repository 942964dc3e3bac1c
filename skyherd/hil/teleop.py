"""Demonstrations flown by a person (`skyherd teleop`): the keyboard of a terminal, or MAVLink
MANUAL_CONTROL from a joystick or a ground station, recorded by policy.demos.record in the
skyherd-demo format (ready for `skyherd train irl|ab|abs-dl --demos FOLDER`).

Keys (raw terminal, no Enter needed):
    w north   s south   d east   a west   r climb   f descend   space hover   q quit (save)
Only the manoeuvres of the chosen scenario are accepted (climb: r; descend: f; lateral: w a s d);
any other key means hover. With step_s S > 0 the task runs in real time: each S seconds the
last key pressed is the action (none → hover). With step_s 0 it waits for one key per step
(turn-based; this is how the tests drive it through a pseudo-terminal). The view is drawn as
text: the camera image scaled to 40×15 characters, 'o' a UGV, '+' the image centre.

MANUAL_CONTROL (e.g. on udpin:127.0.0.1:14560, where QGroundControl or a joystick bridge sends
it): the stick with the largest deflection beyond a dead band picks the action
(`manual_control_action`): x forward → north/south, y right → east/west, z thrust above/below
its 500 centre → climb/descend; button 1 quits. With step_s 0 every MANUAL_CONTROL message is
one step; otherwise the newest message of each step counts and a stick silent for more than
1 s means hover. Continuous (`manual_control_velocity`): the stick stays proportional, x/1000 of
the horizontal speed limit north, y/1000 of it east, thrust (z − 500)/500 of the climb limit
above the centre and of the descent limit below it, the limits being ABS-DL's continuous ones
(policy.absdl.env.velocity_limits); only the scenario's manoeuvres pass. The episode is flown in
policy.absdl.env.ContinuousGroundAirEnv and saved as skyherd-demo/2 with the commanded velocity
of every step (`vel_ned`).
"""

from __future__ import annotations

import os
import select
import sys
import termios
import time
import tty
from dataclasses import dataclass

KEYS = {"w": 1, "s": 2, "d": 3, "a": 4, "r": 5, "f": 6, " ": 0}
STICK_FULL = 1000
"""MANUAL_CONTROL x, y full deflection (−1000..1000); thrust z spans 0..1000."""
THRUST_HOLD = 500
"""MANUAL_CONTROL thrust z at the centre: hold the altitude."""
STICK_SILENT_S = 1.0  # a stick silent for longer than this means hover [s of wall time]


@dataclass(frozen=True)
class TeleopParams:
    scenario: str = "lateral"  # what to demonstrate: lateral, climb, descend or composite
    episodes: int = 1  # episodes to record
    seed: int = 0  # environment seed of the first episode
    step_s: float = 0.5  # wall seconds per step; 0 = wait for a key (a message) each step
    episode_s: float = 60.0  # episode length [s of simulation time]
    view: bool = True  # draw the text view (keyboard)


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


def text_view(env) -> str:
    """The camera image as 40×15 characters: 'o' a UGV in view, '+' the image centre."""
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


class KeyboardPilot:
    """Keys of the terminal `fd` (in cbreak mode) → actions: -1 on q or Ctrl-C (stop)."""

    def __init__(self, fd: int, step_s: float, allowed: tuple[int, ...]) -> None:
        self.fd, self.step_s, self.allowed = fd, step_s, allowed
        self.t_next: float | None = None

    def read_key(self, timeout: float | None) -> str | None:
        r, _, _ = select.select([self.fd], [], [], timeout)
        return os.read(self.fd, 1).decode(errors="ignore") if r else None

    def __call__(self, obs) -> int:
        key = None
        if self.step_s == 0:
            key = self.read_key(None)
        else:
            now = time.monotonic()
            if self.t_next is None:
                self.t_next = now + self.step_s
            while (left := self.t_next - time.monotonic()) > 0:
                k = self.read_key(left)
                if k is not None:
                    key = k
            self.t_next += self.step_s
        if key == "q" or key == "\x03":
            return -1
        a = KEYS.get((key or " ").lower(), 0)
        return a if a in self.allowed else 0


class StickPilot:
    """MANUAL_CONTROL from `link` (hil.link.MavlinkLink) → an action (`action`) or a velocity
    (`velocity`); button 1 stops (-1 / None)."""

    def __init__(self, link, step_s: float) -> None:
        self.link, self.step_s = link, step_s
        self.last = None
        self.t_last = -1e9
        self.t_next: float | None = None

    def newest(self):
        """This step's MANUAL_CONTROL message; None = the stick is silent (hover)."""
        if self.step_s == 0:
            while True:
                for m in self.link.recv(0.5):
                    if m.get_type() == "MANUAL_CONTROL":
                        return m
        if self.t_next is None:
            self.t_next = time.monotonic() + self.step_s
        while (left := self.t_next - time.monotonic()) > 0:
            for m in self.link.recv(min(left, 0.1)):
                if m.get_type() == "MANUAL_CONTROL":
                    self.last, self.t_last = m, time.monotonic()
        self.t_next += self.step_s
        if self.last is None or time.monotonic() - self.t_last > STICK_SILENT_S:
            return None
        return self.last

    def action(self, allowed: tuple[int, ...]):
        """A discrete demonstrator: obs → action index (-1: stop)."""

        def act(obs) -> int:
            m = self.newest()
            if m is not None and m.buttons & 1:
                return -1
            return 0 if m is None else manual_control_action(m.x, m.y, m.z, allowed)

        return act

    def velocity(self, scenario: str, limits):
        """A continuous demonstrator: obs → (3,) NED velocity [m/s] (None: stop)."""

        def act(obs):
            m = self.newest()
            if m is not None and m.buttons & 1:
                return None
            if m is None:
                return (0.0, 0.0, 0.0)
            return manual_control_velocity(m.x, m.y, m.z, scenario, limits)

        return act


def record_keyboard(p: TeleopParams, fd: int):
    """A demonstration from the keyboard of the terminal `fd` (cbreak mode while it records,
    the view on standard output); the terminal's mode comes back on every ending."""
    from skyherd.policy.demos import ALLOWED_ACTIONS, record
    from skyherd.task.params import ACTION_NAMES, TaskParams

    old = termios.tcgetattr(fd)

    def show(env, obs, a) -> None:
        if not p.view:
            return
        m = env.episode_metrics()
        sys.stdout.write(
            "\x1b[H\x1b[2J" + text_view(env) + "\r\n"
            f"{p.scenario}  t={env.formation.t:5.1f}s  alt={env.alt:5.1f} m  "
            f"action={ACTION_NAMES[a]:8s} in view {int(obs[4] * 3)}/3  "
            f"all-in-view so far {m['all_in_view_frac']:.2f}\r\n"
            "w/s north/south  d/a east/west  r climb  f descend  space hover  q quit\r\n"
        )
        sys.stdout.flush()

    try:
        tty.setcbreak(fd)
        sys.stdout.write(f"teleop ready: {p.scenario}, keys w/s/d/a/r/f, space hover, q quit\r\n")
        sys.stdout.flush()
        return record(
            p.scenario,
            KeyboardPilot(fd, p.step_s, ALLOWED_ACTIONS[p.scenario]),
            p.episodes,
            p.seed,
            "teleop:keyboard",
            {"keys": KEYS, "step_s": p.step_s},
            task=TaskParams(episode_s=p.episode_s),
            on_step=show,
        )
    finally:
        termios.tcsetattr(fd, termios.TCSADRAIN, old)


def record_stick(p: TeleopParams, link, address: str, continuous: bool):
    """A demonstration from MANUAL_CONTROL on `link` (at `address`, recorded in the meta):
    discrete actions, or with `continuous` velocities within ABS-DL's limits; "teleop ready"
    on standard output when it listens."""
    from skyherd.policy.absdl.env import velocity_limits
    from skyherd.policy.demos import ALLOWED_ACTIONS, record
    from skyherd.task.params import TaskParams

    stick = StickPilot(link, p.step_s)
    meta = {"address": address, "step_s": p.step_s}
    if continuous:
        limits = meta["velocity_limits"] = velocity_limits()
        act = stick.velocity(p.scenario, limits)
    else:
        act = stick.action(ALLOWED_ACTIONS[p.scenario])
    mode = "continuous" if continuous else "discrete"
    print(f"teleop ready: {p.scenario}, MANUAL_CONTROL on {address} ({mode})", flush=True)
    return record(
        p.scenario,
        act,
        p.episodes,
        p.seed,
        "mavlink:MANUAL_CONTROL" + (":continuous" if continuous else ""),
        meta,
        task=TaskParams(episode_s=p.episode_s),
        continuous=continuous,
    )
