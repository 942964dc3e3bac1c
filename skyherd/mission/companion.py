"""The companion's loop: tick by tick, one or more vehicles, lockstep or free-running.

Lockstep (the built-in vehicle of `skyherd sim`): each tick starts at the vehicle's tick mark
(the camera instant t_k), takes frame k from Zenoh (the bytes received are the bytes detected
on; the mission gets it as a mission.onboard.CameraFrame: pixels, stamp and the autopilot's
estimate at the stamp, never the simulator's header pose), steps the mission once, sends the
setpoint stream and the heartbeat, and closes the tick.

Free-running (a real autopilot, or `skyherd sim --free-run`): the link is drained continuously
and a tick runs every `tick_s` of the autopilot's own clock; the newest frame, if any, is used.

A mission is a generator (mission.steps): `next(gen)` runs one tick; its return ends the flight.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Protocol

from skyherd.flight.autopilot_api import Setpoint
from skyherd.mission.handover import PATIENCE_S, StopRequest, hand_over_all
from skyherd.mission.onboard import CameraFrame, onboard_frame
from skyherd.mission.vehicle import LinkLost, VehicleLink
from skyherd.runio.run import Interrupted


@dataclass(frozen=True)
class CompanionParams:
    """How the companion ticks (saved in config.json)."""

    lockstep: bool = True  # tick on the vehicle's marks (built-in vehicle) or free-run
    tick_s: float = 0.1  # free-running tick period [s of the autopilot's clock]
    heartbeat_s: float = 1.0  # our HEARTBEAT period [s of tick time]
    frame_patience_s: float = 10.0  # lockstep: wait this long [wall s] for tick k's frame
    link_patience_s: float = 60.0  # [wall s] no tick mark (free-running: no message) = gone
    drain_wait_s: float = 0.02  # free-running: wait this long [wall s] for the lead's messages

    def __post_init__(self) -> None:
        if not (self.tick_s > 0 and self.heartbeat_s > 0):
            raise ValueError("tick_s and heartbeat_s must be > 0")


class FrameSource(Protocol):
    def frame_at(self, t: float, patience_s: float,
                 v: VehicleLink | None = None) -> tuple[CameraFrame | None, str]: ...  # fmt: skip
    def newest(self, v: VehicleLink | None = None) -> tuple[CameraFrame | None, str]: ...


class Mission(Protocol):
    name: str

    def on_frame(self, t: float, frame: CameraFrame | None, status: str) -> None: ...


class FrameInbox:
    """Frames of one vehicle from Zenoh (perception.transport.FrameSubscriber), by tick time,
    handed on as the onboard computer has them (mission.onboard.CameraFrame, with vehicle `v`'s
    estimate at the stamp): the companion's only way to a frame.

    `frame_at(t)` returns (frame, "ok") for the frame stamped t, (None, "corrupt") when the
    frame for t arrived damaged (CRC, size: it is dropped, as a real link would), or
    (None, "lost") when nothing came within the patience. A damaged frame counts from the
    moment it arrived, before `frame_at` was called too: the frame is published before its
    tick mark, so it usually arrives first (counted only from the call, a damaged frame that
    came early was missed and its tick waited the whole patience: "lost", seen under load)."""

    def __init__(self, subscriber):
        self.sub = subscriber
        self.ok = self.corrupt = self.lost = 0
        self._corrupt_seen = subscriber.stats.corrupt  # damaged frames already answered for

    def frame_at(self, t: float, patience_s: float, v: VehicleLink | None = None):
        deadline = time.monotonic() + patience_s
        while True:
            fr = self.sub.wait(0.05)
            if fr is not None and abs(fr.t_sim - t) < 1e-6:
                self.ok += 1
                return onboard_frame(fr, v), "ok"
            if self.sub.stats.corrupt > self._corrupt_seen:  # one frame per tick in lockstep
                self._corrupt_seen = self.sub.stats.corrupt
                self.corrupt += 1
                return None, "corrupt"
            if time.monotonic() > deadline:
                self.lost += 1
                return None, "lost"

    def newest(self, v: VehicleLink | None = None):
        fr = self.sub.take()
        return (onboard_frame(fr, v), "ok") if fr is not None else (None, "none")


class LoggedFrames:
    """A FrameSource whose every frame received (ok or corrupt) goes to `log` as (t, status,
    n): frames.csv, what the judge counts the camera's rate on (safety.judge). n: the frames
    the row stands for (free-running, the newest frame is taken and those that came since the
    last take were skipped: 1 + their count)."""

    COLUMNS = ["t", "status", "n"]

    def __init__(self, source: FrameSource, log):
        self.source, self.log = source, log
        stats = getattr(getattr(source, "sub", None), "stats", None)
        self._skipped = (lambda: stats.skipped) if stats is not None else (lambda: 0)
        self._skipped0 = self._skipped()

    def _write(self, t: float, status: str, n: int = 1) -> None:
        try:
            self.log.write({"t": round(float(t), 6), "status": status, "n": n})
        except Exception:  # noqa: BLE001 - the record never stops the flight
            pass

    def frame_at(self, t: float, patience_s: float, v: VehicleLink | None = None):
        fr, status = self.source.frame_at(t, patience_s, v)
        if status != "lost":
            self._write(t, status)
        return fr, status

    def newest(self, v: VehicleLink | None = None):
        fr, status = self.source.newest(v)
        if fr is not None:
            skipped, self._skipped0 = self._skipped() - self._skipped0, self._skipped()
            self._write(fr.t, status, 1 + max(skipped, 0))
        return fr, status


@dataclass
class TickStats:
    ticks: int = 0
    decide_wall_s: list[float] | None = None  # wall time from tick start to close [s]
    cpu_s: float = 0.0  # the loop's CPU time from the first tick on (start-up excluded) [s]
    handover: list[str] | None = None  # stopped by a signal: what was done to each vehicle


def run(v: VehicleLink, mission: Mission, gen, frames: FrameSource | None,
        p: CompanionParams, on_tick=None, stop: StopRequest | None = None) -> TickStats:  # fmt: skip
    """Step `gen` (the mission's generator) once per tick until it returns."""
    return run_fleet([v], mission, gen, frames, p, on_tick and (lambda vs: on_tick(vs[0])), stop)


def _take_marks(vs: list[VehicleLink], taken: list, patience_s: float) -> None:
    """Each vehicle's next tick mark into `taken`, those already taken kept: a signal may
    interrupt the wait between two vehicles, and a mark once taken is never asked for again
    (its simulator waits for that tick's close)."""
    for i, v in enumerate(vs):
        if taken[i] is None:
            t0 = v.t
            try:
                taken[i] = v.next_mark(patience_s)
            except Interrupted:
                if v.t != t0:  # taken just before the signal
                    taken[i] = v.t
                raise


def run_fleet(vs: list[VehicleLink], mission: Mission, gen, frames: FrameSource | None,
              p: CompanionParams, on_tick=None, stop: StopRequest | None = None) -> TickStats:  # fmt: skip
    """One tick for K vehicles at once: in lockstep it starts when every vehicle has marked
    the same instant (their simulations run in parallel between ticks); the frames, if any,
    are vehicle 0's. Free-running, the tick follows vehicle 0's clock.

    `stop` set (a signal): the mission is left and every vehicle is handed to its autopilot
    (mission.handover) in the ticks that follow; then this returns with `handover` filled."""
    stats = TickStats(decide_wall_s=[])
    t_heartbeat = -1e9
    t_next = 0.0
    wall0 = heard = time.monotonic()
    lead = vs[0]
    stop = stop if stop is not None else StopRequest()
    if p.lockstep:  # hello: each simulator starts its clock when this arrives
        stop.waiting = True  # a signal now ends the companion at once: nothing flies yet
        for v in vs:
            v.link.defer_log = True  # a tick's tlog records are written after its close
            v.hello(p.link_patience_s)
        stop.waiting = False
    cpu0 = time.process_time()
    handing = False
    taken: list[float | None] = [None] * len(vs)  # this tick's marks, vehicle by vehicle
    while True:
        if stop.is_set() and not handing:
            handing, gen = True, hand_over_all(vs)
            mission.phase = "hand-over"
        if p.lockstep:
            try:
                stop.waiting = True
                _take_marks(vs, taken, PATIENCE_S if handing else p.link_patience_s)
            except LinkLost as e:
                if not handing:
                    raise
                stats.handover = [f"no tick from the vehicle ({e}): left to its autopilot"]
                return stats
            except Interrupted:  # the first signal while waiting: this tick hands over
                if handing:
                    raise
                continue
            finally:
                stop.waiting = False
            marks, taken = taken, [None] * len(vs)
            if any(abs(m - marks[0]) > 1e-9 for m in marks):
                raise LinkLost(f"the vehicles marked different instants {sorted(set(marks))}: "
                               "are they simulators of one flight, started together?")  # fmt: skip
            t = marks[0]
            start = time.monotonic()
            if frames is not None and not handing:  # only a frame announced for this tick
                if lead.frame_announced_ms == round(t * 1000):
                    mission.on_frame(t, *frames.frame_at(t, p.frame_patience_s, lead))
                else:
                    mission.on_frame(t, None, "lost")
        else:
            if sum([v.drain(p.drain_wait_s if v is lead else 0.0) for v in vs]):
                heard = time.monotonic()
            elif time.monotonic() - heard > p.link_patience_s:
                raise LinkLost(f"nothing from the vehicle for {p.link_patience_s:.0f} s")
            if lead.tel.time_boot_ms == 0:  # nothing yet from the autopilot: wall time counts
                lead.t = time.monotonic() - wall0
            if lead.t < t_next:
                continue
            t_next = lead.t + p.tick_s
            start = time.monotonic()
            if frames is not None:
                fr, status = frames.newest(lead)
                if fr is not None:
                    mission.on_frame(lead.t, fr, status)
        if lead.t - t_heartbeat >= p.heartbeat_s - 1e-9:
            for v in vs:
                v.heartbeat()
            t_heartbeat = lead.t
        try:
            next(gen)
            done = False
        except StopIteration as e:
            done = True
            if handing:
                stats.handover = e.value
        except BaseException:  # what the failing tick queued still goes out (its close not)
            for v in vs:
                v.flush()
            raise
        for v in vs:
            if not done and v.setpoint is not None:
                sp: Setpoint = v.setpoint
                v.position_target(sp.pos_ned, sp.vel_ned, sp.yaw)
        if p.lockstep:
            for v in vs:
                v.close_tick()
        stats.ticks += 1
        stats.decide_wall_s.append(time.monotonic() - start)
        # the tick's bookkeeping (metrics rows, its tlog records) after the close: in lockstep
        # the simulators step on while it is written, instead of waiting for it
        if on_tick is not None:
            on_tick(vs)
        if p.lockstep:
            for v in vs:
                v.link.flush_log()
        if done:
            stats.cpu_s = time.process_time() - cpu0
            return stats
