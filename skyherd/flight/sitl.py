"""SITL runner: one autopilot and its MAVLink endpoint stepping together on one SimClock.

Lockstep: each iteration steps the autopilot by `control_dt` (physics substeps inside), then
lets the endpoint answer what arrived and send what is due at the new simulation time, then
waits for the `Pacer` (speed-up S ≥ 1, or 0 = as fast as possible) once per `pace_s` of
simulation time (a sleep per 4 ms step cost 4.3× the CPU of the unpaced loop), and looks at the
sockets once then: what arrived is answered at the next step (a poll per step was a hovering
vehicle's largest messaging cost, issue 31). Every MAVLink timeout is
measured on the simulation clock, so it scales with S; the trajectory for a given seed and
given inputs does not depend on S.
"""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from skyherd.flight.autopilot_api import Autopilot
from skyherd.flight.clock import Pacer
from skyherd.flight.mavlink import EndpointConfig, MavlinkEndpoint


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
                 pace_s: float = 0.02):  # fmt: skip
        self.autopilot = autopilot
        self.clock = autopilot.clock
        self.pacer = Pacer(speedup)
        self.pace_s = pace_s  # the pacer sleeps once per this much simulation time [s]
        self.endpoint = MavlinkEndpoint(autopilot, config)
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

    def run(self, duration_s: float | None = None, on_step=None) -> RunStats:
        """Step (paced) until `stop()` or until `duration_s` of simulation time has passed.

        The steps between two pace points run as one batch: the stop flag, the end time, the
        pacer and the sockets are looked at once per batch (with `on_step`, the stop flag after
        every step, as `request_stop` promises)."""
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
