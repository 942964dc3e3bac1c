"""`skyherd sim`'s world: the vehicle, the UGV team and the downward camera on one clock.

Per autopilot step (4 ms for the quadrotor) the autopilot and its physics step and the MAVLink
endpoint answers and streams. At every camera instant t_k (10 Hz of simulation time):

1. the UGV team moves to t_k (it stays parked until `ugv_start`: at once, at a time, or when the
   vehicle is first handed to the companion, i.e. enters OFFBOARD);
2. lockstep: the endpoint marks t_k on the API link (flight.lockstep);
3. the camera renders the team from the vehicle's true pose (through a roll/pitch gimbal) and
   publishes the frame on Zenoh `skyherd/<vehicle>/camera/frame`, with t_k and the camera pose
   in its header; the UGVs' truth goes to `skyherd/ugv/<id>/state`, the clock to
   `skyherd/sim/clock`, and one row to world.csv;
4. lockstep: at t_k + L the world waits for the companion's close of tick k and hands the
   messages it sent to the endpoint, in order. Free-running: the API link is read every step
   and each setpoint's lag (now − the frame time it is stamped with) is measured.

Pacing (`speedup`) sleeps once per `pace_s` of simulation time, not once per step.
"""

from __future__ import annotations

import dataclasses
import json
import math
import select
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from skyherd.flight.autopilot_api import FlightMode
from skyherd.flight.clock import Pacer
from skyherd.flight.lockstep import LockstepGate, LockstepTimeout, collect_closes
from skyherd.flight.mavlink.signing import load_key
from skyherd.runio import cut_records, try_write_text
from skyherd.task.params import TaskParams
from skyherd.world.params import WorldParams
from skyherd.world.scene import Scene, during

HEARTBEAT = 0  # MAVLINK_MSG_ID_HEARTBEAT


PARENT_DIED_TICK_WAIT_S = 5.0
"""`skyherd fly` died: how long [s of wall time] a tick waits for the companion's close before
the autopilot steps on alone (its hand-over closes ticks within milliseconds; margin for load)."""


def alone_record(
    why: str,
    t_gone: float,
    t: float,
    alone_s: float,
    modes,
    mode: str,
    armed: bool,
    altitude_m: float,
) -> dict:
    """sim_stats.json's `after_companion`: what the autopilot did once the companion was gone
    (modes: (t, mode, armed) changes), read by report.ending for fly's ending lines."""
    return {
        "why": why,
        "t_gone_s": round(t_gone, 3),
        "span_s": round(t - t_gone, 3),
        "ended": "disarmed" if not armed else f"after alone_s {alone_s:g} s",
        "modes": [{"t": round(tm, 3), "mode": m, "armed": a} for tm, m, a in modes],
        "mode": mode,
        "armed": armed,
        "altitude_m": round(altitude_m, 3) if math.isfinite(altitude_m) else math.nan,
    }


@dataclass
class Lag:
    """Free-running: how late each setpoint acted, now − its stamp [s of simulation time]."""

    samples: list[float] = field(default_factory=list)

    def summary(self) -> dict[str, float]:
        if not self.samples:
            return {"setpoints": 0}
        a = np.array(self.samples)
        return {"setpoints": len(a), "p50_s": float(np.percentile(a, 50)),
                "p95_s": float(np.percentile(a, 95)), "max_s": float(a.max())}  # fmt: skip


class World:
    """One vehicle with its endpoints, the UGV team and the camera. `run()` until `stop()`."""

    def __init__(self, params: WorldParams, session=None, run_dir: Path | None = None,
                 task: TaskParams | None = None, endpoint_config=None, faults=None):  # fmt: skip
        from skyherd.flight.airframes_registry import make_autopilot
        from skyherd.flight.mavlink import EndpointConfig, MavlinkEndpoint

        self.p = params
        self.task = task if task is not None else TaskParams()
        from skyherd.flight.geo import DEFAULT_HOME, Home

        home = DEFAULT_HOME if params.home is None else Home(*params.home, DEFAULT_HOME.heading_rad)
        self.autopilot = make_autopilot(params.airframe, seed=params.seed, instance=params.instance,
                                        faults=faults, home=home)  # fmt: skip
        self.clock = self.autopilot.clock
        cfg = endpoint_config or EndpointConfig(instance=params.instance)
        self.endpoint = MavlinkEndpoint(self.autopilot, cfg)
        self.endpoint.gated.add("api")  # read by the gate (lockstep) or by this loop (free-run)
        self.gate = LockstepGate(self.endpoint.api, self.endpoint.mav, params.lockstep_params)
        self.endpoint.api.coalesce = params.lockstep  # what a tick sends leaves with its mark
        self.pacer = Pacer(params.speedup)
        self.lag = Lag()
        self._stop = threading.Event()
        self._alone = threading.Event()  # the companion is gone: the autopilot flies alone
        self._begun = False  # begin() ran: the flight's ticks have started
        self.fly_died = ""  # why, once `skyherd fly` died (parent_died)
        self.alone_why = ""
        self.alone: dict | None = None  # what the autopilot did alone (sim_stats.json)
        self._session = session
        key = load_key(cfg.signing_key) if cfg.signing_key else None  # frames signed too
        self.scene = Scene(params, self.task, session, run_dir, key)
        self.run_dir = self.scene.run_dir
        self.cut_dropped = 0  # companion messages lost in link cuts
        self.camera_dropped = 0  # frames not sent while the camera was lost

    # ---- the loop ------------------------------------------------------------------------------
    def stop(self) -> None:
        """Ask `run` to return (safe from a signal handler or another thread)."""
        self._stop.set()

    def companion_gone(self, why: str) -> None:
        """The companion is gone (`skyherd fly` saw it exit and sent SIGUSR1, or the parent
        died, or a lockstep tick timed out): from the next step the vehicle steps without
        waiting for it, as fast as possible, so that the autopilot's own failsafe acts; the run
        ends once the autopilot disarms or `alone_s` of simulation time have passed (safe from
        a signal handler)."""
        if not self._alone.is_set():
            self.alone_why = why
        self._alone.set()

    def parent_died(self, why: str) -> None:
        """`skyherd fly` died (kill -9): the companion got its own parent-death signal and is
        handing over, which in lockstep needs its ticks. So once flying the simulator keeps
        them, waiting PARENT_DIED_TICK_WAIT_S of wall time per tick instead of the usual
        timeout, and steps on alone when the companion stops closing them (it ended, or died
        too); before the flight or free-running, alone at once. Safe from a signal handler."""
        self.fly_died = why
        if self.p.lockstep and self._begun and not self._alone.is_set():
            self.gate.p = dataclasses.replace(
                self.gate.p, timeout_s=min(self.gate.p.timeout_s, PARENT_DIED_TICK_WAIT_S)
            )
        else:
            self.companion_gone(why)

    def run(self, duration_s: float | None = None) -> dict:
        """Step until `stop()` (or `duration_s` of simulation time); return the run's stats."""
        return run_worlds([self], self.pacer, duration_s)[0]

    # One world's loop in three parts, so that several worlds (a fleet: `skyherd sim --fleet`) can
    # share one process and one pacer: `begin`, then steps (`start_step`, `close_due` /
    # `take_close`, `finish_step`) until `start_step` returns False, then `finish`.
    def begin(self, duration_s: float | None = None) -> None:
        """Start the run's counters (after the companion's hello, in lockstep)."""
        p, clock = self.p, self.clock
        self._begun = True
        self._step_us = round(self.autopilot.control_dt * 1e6)
        self._period_us = round(1e6 / p.camera_hz)
        self._latency_us = round(p.lockstep_params.latency_s * 1e6 / self._step_us) * self._step_us
        self._t_end_us = None if duration_s is None else clock.time_us + round(duration_s * 1e6)
        self._next_frame_us = clock.time_us
        self._open_tick: int | None = None  # camera instant whose close is awaited [µs]
        self._alone_t0: float | None = None  # simulation time the companion was found gone [s]
        self._t0 = (time.monotonic(), clock.t, time.process_time())  # wall, sim, CPU
        self._span = None  # (sim, wall, CPU) seconds from the start to the last tick closed
        self._cut = False  # the API link is cut now (link_cuts)
        self._read_fds = frozenset(link.sock.fileno() for link in self.endpoint.read_links())
        self._api_fd = self.endpoint.api.sock.fileno()
        self.endpoint.update()

    def beacon(self) -> None:
        """The vehicle's heartbeat on the API link, while it waits for the companion's hello."""
        self.endpoint.api.send(self.endpoint._build(HEARTBEAT))

    def sockets(self) -> list:
        """The sockets `step` reads: the endpoint's ungated links, and free-running the API link
        (in lockstep the gate reads it, blocking, at each close)."""
        gated = self.p.lockstep and self._alone_t0 is None
        links = self.endpoint.read_links() + ([] if gated else [self.endpoint.api])
        return [link.sock for link in links]

    # One step in three parts, so that a fleet marks all its vehicles' camera instants, then
    # waits for all their closes at once, then steps them (`run_worlds`): the companion's burst
    # of closes wakes the process once, not once per vehicle.
    def start_step(self) -> bool:
        """What falls due before the step: the camera instant (rendered, published, marked).
        False when the run is over (stopped, or out of time)."""
        p, clock = self.p, self.clock
        if self._stop.is_set():
            return False
        t_us = clock.time_us
        if self._t_end_us is not None and t_us >= self._t_end_us:
            return False
        if t_us >= self._next_frame_us:
            self._camera_instant(t_us)
            self._next_frame_us += self._period_us
            self._open_tick = t_us if p.lockstep and self._alone_t0 is None else None
        self._cut = bool(p.link_cuts) and during(p.link_cuts, clock.t)
        self.endpoint.api.muted = self._cut  # a real cut: nothing reaches the companion
        return True

    def close_due(self) -> int | None:
        """Lockstep: the tick [µs] whose close the companion must have sent before this step
        (at t_k + L), else None."""
        tick = self._open_tick
        if tick is not None and self.clock.time_us >= tick + self._latency_us:
            return tick
        return None

    def take_close(self, batch: list) -> None:
        """The companion's messages of the tick just closed, handed to the vehicle in order."""
        clock, ep = self.clock, self.endpoint
        wall0, sim0, cpu0 = self._t0
        self._span = (clock.t - sim0, time.monotonic() - wall0, time.process_time() - cpu0)
        if not self._cut:  # ... and nothing from the companion reaches the vehicle
            ep.dispatch(ep.api, self._gimbal_commands(batch))
        else:
            self.cut_dropped += len(batch)
        self._open_tick = None

    def finish_step(self, ready: set[int] | None = None) -> None:
        """The autopilot's step and the endpoint's. `ready`: the file descriptors of
        `sockets()` that have data (a fleet polls them all at once); None: polled here."""
        free = not self.p.lockstep or self._alone_t0 is not None
        if free and (ready is None or self._api_fd in ready):
            self._free_run_receive()
        self.autopilot.step()
        self.endpoint.update(None if ready is None else not ready.isdisjoint(self._read_fds))

    # ---- the autopilot alone, after the companion ----------------------------------------------
    def go_alone(self) -> None:
        """Step on without the companion from now (its open tick is dropped)."""
        self._alone_t0 = self.clock.t
        self._open_tick = None
        ap = self.autopilot
        self._alone_modes = [(self.clock.t, ap.mode.name, bool(ap.armed))]

    def watch_alone(self) -> None:
        """Note the autopilot's mode and arming changes while it flies alone."""
        ap = self.autopilot
        last = self._alone_modes[-1]
        if ap.mode.name != last[1] or bool(ap.armed) != last[2]:
            self._alone_modes.append((self.clock.t, ap.mode.name, bool(ap.armed)))

    def end_alone(self) -> None:
        """What the autopilot did alone: its modes, and where the vehicle is at the end."""
        ap = self.autopilot
        state = ap.true_state if hasattr(ap, "true_state") else ap.state
        t = self.clock.t
        # world.csv ends on the end state, if the autopilot flew alone at all (a flight that
        # ended disarmed keeps the world.csv it always had)
        if t > max(self.scene.truth_t, self._alone_t0):
            self.scene.write_truth(t, state, ap.mode.name, bool(ap.armed))
        self.alone = alone_record(self.alone_why, self._alone_t0, t, self.p.alone_s,
                                  self._alone_modes, ap.mode.name, bool(ap.armed),
                                  -float(state.pos_ned[2]))  # fmt: skip

    def finish(self, process_vehicles: int = 1) -> dict:
        """The run's stats (written to sim_stats.json); `process_vehicles` worlds shared the
        process, its CPU time and its wall time."""
        wall0, sim0, cpu0 = self._t0
        return self._stats(self.clock.t - sim0, time.monotonic() - wall0, time.process_time() - cpu0,
                           self._span, process_vehicles)  # fmt: skip

    def _camera_instant(self, t_us: int) -> None:
        ap = self.autopilot  # the physics, not the estimate, where the two differ
        state = ap.true_state if hasattr(ap, "true_state") else ap.state
        seq = self.scene.instant(t_us / 1e6, state, ap.mode.name, bool(ap.armed),
                                 offboard=ap.mode is FlightMode.OFFBOARD)  # fmt: skip
        if self.p.lockstep:
            self.gate.mark(t_us, seq)

    def _gimbal_commands(self, batch: list) -> list:
        """The gimbal manager on the vehicle: MAV_CMD_DO_SET_ROI_LOCATION (COMMAND_LONG, params
        5–7 = lat [deg], lon [deg], alt AMSL [m]) points the pointed camera there and is
        acknowledged here; every other message goes on to the autopilot, in order."""
        if self.p.camera != "roi":
            return batch
        from pymavlink.dialects.v20 import ardupilotmega as M

        from skyherd.perception.gimbal import roi_ned

        rest = []
        for msg, src in batch:
            if msg.get_type() == "COMMAND_LONG" and msg.command == M.MAV_CMD_DO_SET_ROI_LOCATION:
                target = roi_ned(self.autopilot.home, msg.param5, msg.param6, msg.param7)
                ok = target is not None
                if ok:
                    self.scene.point(target)
                res = M.MAV_RESULT_ACCEPTED if ok else M.MAV_RESULT_DENIED
                ep = self.endpoint
                ack = ep.mav.command_ack_encode(msg.command, res, 0, 0, msg.get_srcSystem(),
                                                msg.get_srcComponent())  # fmt: skip
                ep.api.send(ack, to=src)
            else:
                rest.append((msg, src))
        return rest

    def _free_run_receive(self) -> None:
        got = self.endpoint.api.receive()
        if not got:
            return
        now = self.clock.t
        for msg, _ in got if not self.p.lockstep else ():  # (lockstep: read only when alone)
            if msg.get_type().startswith("SET_POSITION_TARGET"):
                self.lag.samples.append(now - msg.time_boot_ms / 1000.0)
        self.endpoint.dispatch(self.endpoint.api, self._gimbal_commands(got))

    def _stats(self, sim_s: float, wall_s: float, cpu_s: float = 0.0, span=None,
               process_vehicles: int = 1) -> dict:  # fmt: skip
        """The run's figures. In lockstep the flight is the span up to the last tick the
        companion closed: after it the simulator only waits (for a companion that ended, until
        `skyherd fly` stops it), which is not simulation, so the real-time factor and the CPU
        per simulated second are taken over that span."""
        g = self.gate.stats
        f_sim, f_wall, f_cpu = span if span is not None else (sim_s, wall_s, cpu_s)
        stats = {
            "sim_s": sim_s,
            "wall_s": wall_s,
            "cpu_s": cpu_s,  # this process's CPU time while it ran (load-independent cost)
            "process_vehicles": process_vehicles,  # worlds sharing that CPU time (a fleet: > 1)
            "flight_sim_s": f_sim,  # lockstep: up to the last closed tick (else the whole run)
            "flight_wall_s": f_wall,
            "flight_cpu_s": f_cpu,
            "real_time_factor": f_sim / f_wall if f_wall > 0 else math.inf,
            "frames": self.scene.frames,
            "render_failures": self.scene.render_failures,
            "lockstep": self.p.lockstep,
            "ticks_closed": g.ticks,
            "mark_resends": g.resends,
            "wait_for_companion_wall_s": g.wait_wall_s,
            "free_run_lag": self.lag.summary(),
            "link_cut_dropped": self.cut_dropped,
            "link_cut_muted": self.endpoint.api.stats_muted,
            "camera_loss_frames": self.scene.camera_dropped,
            "mavlink_signing": {
                "on": self.endpoint.signing.enabled,
                **dict(sorted(self.endpoint.signing.stats.items())),
            },  # fmt: skip
            "after_companion": self.alone,
            "records_cut": cut_records([self.scene.truth]),
        }
        if self.run_dir is not None:
            try_write_text(self.run_dir / "sim_stats.json", json.dumps(stats, indent=2) + "\n")
        return stats

    def close(self) -> None:
        self.scene.close()
        self.endpoint.close()


def run_worlds(worlds: list[World], pacer: Pacer, duration_s: float | None = None) -> list[dict]:
    """Run worlds that share one process and one clock rate, one step of each in turn, until
    any of them ends (stopped, out of time, its companion gone); their stats, in order.

    Each world keeps its own lockstep with its companion: at a camera instant every world marks
    it, at t + L the process waits for all their closes at once (`collect_closes`), so a fleet
    flies exactly as the same vehicles in one process each. Pacing sleeps once per `pace_s` of simulation time for all of them."""
    steps = {round(w.autopilot.control_dt * 1e6) for w in worlds}
    if len(steps) != 1:
        raise ValueError(
            f"worlds of one process must share the control step, not {sorted(steps)} us"
        )
    first = worlds[0]
    if first.p.lockstep and not wait_for_peers(worlds):
        return [w._stats(0.0, 0.0, process_vehicles=len(worlds)) for w in worlds]
    for w in worlds:
        w.begin(duration_s)
    pace_us = max(first._step_us, round(first.p.pace_s * 1e6))
    next_pace_us = first.clock.time_us
    poller = select.poll() if hasattr(select, "poll") else None
    for sock in (s for w in worlds for s in w.sockets()) if poller is not None else ():
        poller.register(sock.fileno(), select.POLLIN)
    stopped = lambda: any(w._stop.is_set() or w._alone.is_set() for w in worlds)  # noqa: E731
    # One system call per `pace_s` of simulation time (with the pacer's sleep, and on after the
    # companion is gone) tells which of the fleet's sockets have data; the steps between read
    # nothing (a poll per 4 ms step was a hovering vehicle's largest messaging cost, issue 31).
    idle: set[int] | None = set() if poller is not None else None  # None: each step polls
    ready = readable(poller) if poller is not None else None
    next_poll_us = first.clock.time_us + pace_us
    alone_end_us: int | None = None  # the companion gone: the autopilot alone until then [µs]
    while True:
        if alone_end_us is None and any(w._alone.is_set() for w in worlds):
            alone_end_us = first.clock.time_us + round(first.p.alone_s * 1e6)
            why = next(w.alone_why for w in worlds if w._alone.is_set())
            for w in worlds:  # one companion flew them all: all are alone now
                w.companion_gone(why)
                w.go_alone()
                if poller is not None and w.p.lockstep:  # its API link is read here now
                    poller.register(w.endpoint.api.sock.fileno(), select.POLLIN)
        if alone_end_us is not None:
            for w in worlds:
                w.watch_alone()
            if first.clock.time_us >= alone_end_us or not any(w.autopilot.armed for w in worlds):
                for w in worlds:
                    w.end_alone()
                break
        if not all(w.start_step() for w in worlds):
            if alone_end_us is not None:
                for w in worlds:
                    w.end_alone()
            break
        due = [(w, tick) for w in worlds if (tick := w.close_due()) is not None]
        if due:
            try:
                batches = collect_closes(
                    [(w.gate, tick, w.scene.republish) for w, tick in due], stopped
                )
            except LockstepTimeout as e:  # the companion is stuck or gone: the autopilot alone
                died = next((w.fly_died for w in worlds if w.fly_died), "")
                first.companion_gone(f"{died}; then the companion stopped closing ticks" if died
                                     else f"lockstep: {e}")  # fmt: skip
                continue
            if batches is None:
                if any(w._stop.is_set() for w in worlds):
                    break
                continue  # the companion is gone: the next round steps alone
            for (w, _), batch in zip(due, batches, strict=True):
                w.take_close(batch)
        for w in worlds:
            w.finish_step(ready)
        ready = idle
        if alone_end_us is None and first.clock.time_us >= next_pace_us:
            pacer.wait_until(first.clock.t)  # alone: as fast as possible
            next_pace_us += pace_us
        if poller is not None and first.clock.time_us >= next_poll_us:
            ready = readable(poller)
            next_poll_us += pace_us
    return [w.finish(len(worlds)) for w in worlds]


def readable(poller: select.poll) -> set[int]:
    """The registered file descriptors with data to read (POLLIN; a socket that only has ICMP
    refusals queued, POLLERR, has nothing for `receive`)."""
    return {fd for fd, ev in poller.poll(0) if ev & select.POLLIN}


def wait_for_peers(worlds: list[World]) -> bool:
    """Lockstep: block until every world's companion has said hello, beaconing each world's
    heartbeat while it waits (a companion may wait for all its vehicles before it speaks).
    False when any world is stopped first."""
    waiting = list(worlds)
    while waiting:
        waiting = [w for w in waiting if not w.gate.poll_peer(w.beacon)]
        if any(w._stop.is_set() or w._alone.is_set() for w in worlds):
            return False
        if waiting:
            select.select([w.gate.link.sock for w in waiting], [], [],
                          min(w.gate.p.beacon_s for w in waiting))  # fmt: skip
    return True
