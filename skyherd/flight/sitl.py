"""SITL runner: one autopilot and its MAVLink endpoint stepping together on one SimClock.

Lockstep: each iteration steps the autopilot by `control_dt` (physics substeps inside), then
lets the endpoint answer what arrived and send what is due at the new simulation time, then
waits for the `Pacer` (speed-up S ≥ 1, or 0 = as fast as possible) once per `pace_s` of
simulation time (a sleep per 4 ms step cost 4.3× the CPU of the unpaced loop), and looks at the
sockets once then: what arrived is answered at the next step (a poll per step was a hovering
vehicle's largest messaging cost, issue 31). Every MAVLink timeout is
measured on the simulation clock, so it scales with S; the trajectory for a given seed and
given inputs does not depend on S.

Lockstep with a companion (`lockstep=LockstepParams(...)`: the drills through the mission code,
mission.drill_link): the API link is read by a flight.lockstep gate instead; every `tick_s` of
simulation time the vehicle marks the instant, and it does not step past the mark + L until the
companion's close has arrived (what it sent before the close is handled then, in order), as
`skyherd sim` does with its built-in vehicle (world.sim). The run then goes as fast as both
sides compute, and the flight depends on simulation time only.
"""

from __future__ import annotations

import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from skyherd.flight.autopilot_api import Autopilot
from skyherd.flight.clock import Pacer
from skyherd.flight.lockstep import LockstepGate, LockstepParams
from skyherd.flight.mavlink import EndpointConfig, MavlinkEndpoint
from skyherd.runio.constants import PACE_S


@dataclass(frozen=True)
class RunStats:
    """What one `run` did: simulation and wall time [s], steps, real-time factor."""

    sim_s: float
    wall_s: float
    steps: int

    @property
    def real_time_factor(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else float("inf")


class Sitl:
    """A simulated vehicle with its endpoints. Use as a context manager to close the sockets."""

    def __init__(self, autopilot: Autopilot, config: EndpointConfig, speedup: float = 1.0,
                 pace_s: float = PACE_S, lockstep: LockstepParams | None = None,
                 tick_s: float = 0.1):  # fmt: skip
        self.autopilot = autopilot
        self.clock = autopilot.clock
        self.pacer = Pacer(speedup)
        self.pace_s = pace_s  # the pacer sleeps once per this much simulation time [s]
        self.endpoint = MavlinkEndpoint(autopilot, config)
        self.gate: LockstepGate | None = None  # lockstep: the API link's barrier
        self.tick_s = tick_s  # lockstep: the companion's tick period [s of simulation time]
        if lockstep is not None:
            if not tick_s > 0:
                raise ValueError(f"tick_s must be > 0, got {tick_s}")
            self.endpoint.gated.add(self.endpoint.api.name)
            self.gate = LockstepGate(self.endpoint.api, self.endpoint.mav, lockstep)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.steps = 0

    @property
    def speedup(self) -> float:
        return self.pacer.speedup

    def step(self) -> None:
        """One lockstep iteration: autopilot, then MAVLink at the new time."""
        self.autopilot.step()
        self.endpoint.update()
        self.steps += 1

    def run(self, duration_s: float | None = None, on_step=None,
            on_close: Callable[[list], list] | None = None) -> RunStats:  # fmt: skip
        """Step (paced) until `stop()` or until `duration_s` of simulation time has passed.
        `on_step(sitl)` after every step; lockstep: see `_run_lockstep`.

        The steps between two pace points run as one batch: the stop flag, the end time, the
        pacer and the sockets are looked at once per batch (with `on_step`, the stop flag after
        every step, as `request_stop` promises)."""
        if self.gate is not None:
            return self._run_lockstep(duration_s, on_step, on_close)
        clock, ap, ep = self.clock, self.autopilot, self.endpoint
        step_us = round(ap.control_dt * 1e6)
        pace_us = max(1, round(self.pace_s * 1e6))
        t_end_us = None if duration_s is None else clock.time_us + round(duration_s * 1e6)
        sim0, wall0, steps0 = clock.t, time.monotonic(), self.steps
        ep.update()  # answer anything that arrived before the first step
        next_pace_us = clock.time_us
        readable = False
        while not self._stop.is_set():
            now_us = clock.time_us
            if t_end_us is not None and now_us >= t_end_us:
                break
            n = max(1, -(-(next_pace_us - now_us) // step_us))  # steps to the pace point
            if t_end_us is not None:
                n = min(n, -(-(t_end_us - now_us) // step_us))
            if on_step is None:
                step, update = ap.step, ep.update
                step()
                update(readable)
                for _ in range(n - 1):
                    step()
                    update(False)
                self.steps += n
            else:
                for i in range(n):
                    ap.step()
                    ep.update(readable and i == 0)
                    self.steps += 1
                    on_step(self)
                    if self._stop.is_set():
                        break
            readable = False
            if clock.time_us >= next_pace_us:  # one sleep per batch of steps, not per step
                self.pacer.wait_until(clock.t)
                next_pace_us += pace_us
                readable = ep.poll()  # and one look at the sockets
        return RunStats(clock.t - sim0, time.monotonic() - wall0, self.steps - steps0)

    def _run_lockstep(self, duration_s: float | None, on_step,
                      on_close: Callable[[list], list] | None) -> RunStats:  # fmt: skip
        """`run` in lockstep with a companion: a step at a time, the endpoint polled every step
        (the API link is read at the barriers only), `on_close(batch)` what of the companion's
        closed tick reaches the vehicle (a link cut: nothing)."""
        if not self._wait_hello():
            return RunStats(0.0, 0.0, 0)
        t_end = None if duration_s is None else self.clock.t + duration_s
        sim0, wall0, steps0 = self.clock.t, time.monotonic(), self.steps
        self.endpoint.update()  # answer anything that arrived before the first step
        next_pace = self.clock.t
        step_us = round(self.autopilot.control_dt * 1e6)
        period_us = round(self.tick_s * 1e6)
        latency_us = (
            0 if self.gate is None else round(self.gate.p.latency_s * 1e6 / step_us) * step_us
        )
        next_tick, open_tick = self.clock.time_us, None
        # lockstep: a stop ends the run at the next barrier only (a stop between two would end
        # it after as many steps as the threads' timing allowed)
        while self.gate is not None or not self._stop.is_set():
            if t_end is not None and self.clock.t >= t_end - 1e-9:
                break
            if self.gate is not None:  # the tick's mark, and at mark + L its close
                t_us = self.clock.time_us
                if t_us >= next_tick:
                    self.gate.mark(t_us)
                    open_tick, next_tick = t_us, next_tick + period_us
                if open_tick is not None and t_us >= open_tick + latency_us:
                    batch = self.gate.collect(open_tick, self._stop)
                    if batch is None:
                        break
                    self.endpoint.dispatch(
                        self.endpoint.api, on_close(batch) if on_close else batch
                    )
                    open_tick = None
            self.step()
            if on_step is not None:
                on_step(self)
            if self.clock.t >= next_pace - 1e-9:  # one sleep per batch of steps, not per step
                self.pacer.wait_until(self.clock.t)
                next_pace += self.pace_s
        return RunStats(self.clock.t - sim0, time.monotonic() - wall0, self.steps - steps0)

    def _wait_hello(self) -> bool:
        """Lockstep: beacon the heartbeat until the companion's hello; False if stopped."""
        gate = self.gate
        while not gate.poll_peer(lambda: self.endpoint.api.send(self.endpoint._build(0))):
            if self._stop.is_set():
                return False
            select.select([gate.link.sock], [], [], gate.p.beacon_s)
        return True

    def start(self, duration_s: float | None = None) -> Sitl:
        """Run on a background thread (tests, tools); `stop()` ends it."""
        self._stop.clear()
        self._thread = threading.Thread(
            target=self.run, args=(duration_s,), name="sitl", daemon=True
        )
        self._thread.start()
        return self

    def request_stop(self) -> None:
        """Ask `run` to return after the current step (safe from a signal handler)."""
        self._stop.set()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=10.0)
            self._thread = None

    def close(self) -> None:
        self.stop()
        self.endpoint.close()

    def __enter__(self) -> Sitl:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
