"""One simulation clock for air and ground, and a pacer that maps it onto wall time.

Simulation time is kept as integer microseconds so that stepping is exact and
deterministic: 1000 steps of 1 ms are exactly 1 s, at any speed-up.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

US_PER_S = 1_000_000
FREE_RUN_SPEEDUP = (
    10.0  # `fly` / `sim`'s pace when free-running (a pacer is needed) [sim s / wall s]
)
SPEEDUP_HELP = ("simulation seconds per wall second; 0 = as fast as possible (default: 0 in "
                "lockstep, where the flight is the same at any speed-up; "
                f"{FREE_RUN_SPEEDUP:g} when free-running, which needs a pacer)")  # fmt: skip


def default_speedup(given: float | None, free_running: bool) -> float:
    """--speedup as given, or its default: 0 (as fast as possible) in lockstep, where the
    flight does not depend on it; FREE_RUN_SPEEDUP when nothing waits for the companion."""
    if given is not None:
        return given
    return FREE_RUN_SPEEDUP if free_running else 0.0


@dataclass
class SimClock:
    """Simulation time. `advance` is the only way time moves."""

    time_us: int = 0

    @property
    def t(self) -> float:
        """Simulation time [s]."""
        return self.time_us / US_PER_S

    @property
    def time_boot_ms(self) -> int:
        """MAVLink `time_boot_ms` [ms], from simulation time (never the wall clock)."""
        return self.time_us // 1000

    def advance(self, dt_us: int) -> None:
        if dt_us <= 0:
            raise ValueError(f"clock can only move forward, got dt={dt_us} us")
        self.time_us += int(dt_us)


@dataclass
class Pacer:
    """Keeps simulation time at `speedup` × wall time.

    speedup == 0 means as fast as possible (nothing external paces the simulation).
    A pause (the process being stopped, a slow step) is not caught up in a burst: when
    the simulation falls more than `max_lag_s` of wall time behind, the pacer re-anchors.
    """

    speedup: float = 1.0
    max_lag_s: float = 0.25
    _wall0: float = field(default=0.0, init=False)
    _sim0: float = field(default=0.0, init=False)
    _started: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        if not (self.speedup == 0 or self.speedup >= 1.0):
            raise ValueError(f"speedup must be 0 (as fast as possible) or >= 1, got {self.speedup}")

    def wall_to_sim(self, wall_s: float) -> float:
        """Scale a wall-clock duration [s] into simulation time [s]."""
        return wall_s * self.speedup if self.speedup > 0 else wall_s

    def sim_to_wall(self, sim_s: float) -> float:
        """Scale a simulation-time duration [s] into wall time [s] (0 when unpaced)."""
        return sim_s / self.speedup if self.speedup > 0 else 0.0

    def wait_until(self, sim_t: float) -> None:
        """Sleep until wall time has caught up with simulation time `sim_t` [s]."""
        if self.speedup == 0:
            return
        now = time.monotonic()
        if not self._started:
            self._wall0, self._sim0, self._started = now, sim_t, True
            return
        target = self._wall0 + (sim_t - self._sim0) / self.speedup
        lag = now - target
        if lag > self.max_lag_s:
            self._wall0, self._sim0 = now, sim_t
        elif lag < 0:
            time.sleep(-lag)
