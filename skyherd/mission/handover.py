"""The companion's way out: told to stop (SIGINT, SIGTERM, SIGHUP, or its parent died), it does
not go silent mid-air; it hands every vehicle it flies to its autopilot, then exits.

Per vehicle, in the ticks that follow the request:
- disarmed, on the ground, or already in LAND or RTL (the autopilot's own landing or return,
  never undone): nothing to do;
- otherwise the autopilot profile's landing recipe up to the mode switch (PX4 and the built-in
  vehicle: AUTO.LAND; ArduCopter: LAND; ArduPlane: RTL), with a hold at the present position
  streamed until the switch, then no more setpoints. It does not wait for the landing: the
  autopilot lands by itself (the simulator steps on alone until it has disarmed).
A refused switch leaves the vehicle to the autopilot's offboard-loss failsafe (PX4: Hold after
COM_OF_LOSS_T), which acts once the setpoints stop.

`StopRequest` is what the signal handler sets. While the loop waits for the vehicle's next
tick, the handler raises `Interrupted` instead, so a vehicle that is gone (its simulator died)
costs `PATIENCE_S` of wall time, not the link's full patience; a second signal always raises.
`stop_on_signals` installs that handler for the flight's loop.
"""

from __future__ import annotations

import contextlib
import signal
from collections.abc import Generator

from pymavlink.dialects.v20 import ardupilotmega as M

from skyherd.flight.autopilot_api import FlightMode, Setpoint
from skyherd.mission.steps import MissionError, recipe
from skyherd.mission.vehicle import VehicleLink
from skyherd.runio.run import Interrupted
from skyherd.runio.signals import say_ready

PATIENCE_S = 3.0  # wall time to wait for a tick mark while handing over [s]
LEFT_ALONE = (FlightMode.LAND, FlightMode.RTL)  # the autopilot lands or returns by itself
SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
"""End the flight by handing the vehicles to their autopilots; a second one ends the companion
at once."""
PARENT_DIED = signal.SIGUSR1
"""The companion's parent-death signal under `skyherd fly` (runio.launch): hand over as
above. The kernel sends it once per thread of the dying parent (each thread that exits hands
its children to the next and signals them again), spread over as long as the dying threads
wait for a CPU: a repeat never counts as a second signal, and one after the flight's loop is
ignored (its default would end the companion before companion.json is written)."""


class StopRequest:
    """The signal that asked the companion to stop (set from a signal handler)."""

    def __init__(self) -> None:
        self.signum: int | None = None
        self.waiting = False  # the loop blocks on the vehicle: a signal raises at once

    def is_set(self) -> bool:
        return self.signum is not None

    def request(self, signum: int, again_ends: bool = True) -> None:
        """The signal handler: note the first signal; raise when the loop is waiting, or on a
        second signal unless `again_ends` is False (a parent-death signal can come twice)."""
        first = self.signum is None
        if first:
            self.signum = signum
        if (self.waiting and first) or (not first and again_ends):
            raise Interrupted(signum)


@contextlib.contextmanager
def stop_on_signals(stop: StopRequest):
    """SIGINT, SIGTERM and SIGHUP set `stop` (a second one, or one before the flight, raises
    runio.Interrupted) while the block runs, and so does PARENT_DIED (never a second); the
    previous handlers afterwards, except PARENT_DIED's: ignored from then on (the loop is
    over, the records are still to be written)."""

    def on_signal(signum, _frame) -> None:
        stop.request(signum, again_ends=signum != PARENT_DIED)

    stop.waiting = True  # until the loop takes over (mission.companion): nothing flies yet
    old = {sig: signal.signal(sig, on_signal) for sig in SIGNALS}
    signal.signal(PARENT_DIED, on_signal)
    say_ready()  # `skyherd fly` may send its SIGINT now (runio.launch)
    try:
        yield stop
    finally:
        signal.signal(PARENT_DIED, signal.SIG_IGN)
        for sig, h in old.items():
            signal.signal(sig, h)


def signal_name(x) -> str:
    """The signal of an Interrupted or a StopRequest by name (a bare Ctrl-C's is SIGINT; the
    parent-death signal says so)."""
    signum = getattr(x, "signum", None)
    name = signal.Signals(signum).name if signum else "SIGINT"
    return name + (": its parent died" if signum == PARENT_DIED else "")


def hand_over(v: VehicleLink) -> Generator[None, None, str]:
    """One vehicle to its autopilot (module docstring); returns what was done, in words."""
    tel, prof = v.tel, v.profile
    where = _where(v)
    if not tel.armed or tel.landed_state == M.MAV_LANDED_STATE_ON_GROUND or prof is None:
        v.setpoint = None
        return f"nothing to hand over ({'disarmed' if not tel.armed else 'on the ground'}{where})"
    if tel.mode in LEFT_ALONE:
        v.setpoint = None
        return f"left to the autopilot in {tel.mode.name}{where}"
    if tel.pos_ned is not None:
        v.setpoint = Setpoint(pos_ned=tel.pos_ned.copy(), yaw=v.setpoint.yaw if v.setpoint else 0.0)
    steps = tuple(st for st in prof.land_steps() if st.kind != "wait_disarmed")
    try:
        yield from recipe(v, steps)
    except MissionError as e:
        v.setpoint = None
        return f"hand-over refused ({e}): left to the autopilot's failsafe{where}"
    v.setpoint = None
    mode = tel.mode.name if tel.mode is not None else "?"
    return f"handed to the autopilot: {mode}{_where(v)}"


def hand_over_all(vs: list[VehicleLink]) -> Generator[None, None, list[str]]:
    """Every vehicle at once, one tick at a time; what was done to each."""
    gens = [hand_over(v) for v in vs]
    done: list[str | None] = [None] * len(vs)
    while True:
        for i, g in enumerate(gens):
            if done[i] is None:
                try:
                    next(g)
                except StopIteration as e:
                    done[i] = e.value
        if all(d is not None for d in done):
            if len(vs) == 1:
                return [d for d in done if d is not None]
            return [f"uav{k}: {d}" for k, d in enumerate(done)]
        yield


def _where(v: VehicleLink) -> str:
    p = v.tel.pos_ned
    return "" if p is None else f" at {-float(p[2]):.1f} m, t = {v.t:.1f} s"
