"""The phases every mission shares, flown through `VehicleClient`: connect, arm, take off,
hand over to offboard, land. Telemetry is recorded to metrics.csv on every position sample,
and a mission supplies the offboard setpoint for each sample.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from flight.autopilot_api import FlightMode
from hil.client import Telemetry, VehicleClient
from runio.runfolder import CsvWriter

SetpointFn = Callable[[Telemetry], tuple | None]

TRACK_COLUMNS = ["t", "north", "east", "down", "vn", "ve", "vd", "mode", "armed", "phase"]


class FlightSession:
    """One flight through a client, with a progress bar and a wall-clock limit [s]."""

    def __init__(self, client: VehicleClient, metrics: CsvWriter, steps: list[str], timeout: float):
        self.client = client
        self.tel = client.telemetry
        self.metrics = metrics
        self.track: list[tuple[float, float, float, float]] = []
        self.phase = "connect"
        self.hold_target: np.ndarray | None = None  # offboard position target between missions
        self.mission_fn: SetpointFn | None = None
        self.t_end = time.monotonic() + timeout
        self.bar = tqdm(total=len(steps), desc="fly", unit="step", leave=True)
        client.stream_offboard(self._setpoint)

    # ---- per telemetry sample (receive thread) ---------------------------------------------
    def _setpoint(self, tel: Telemetry):
        self._record(tel)
        if self.mission_fn is not None:
            return self.mission_fn(tel)
        return None if self.hold_target is None else (self.hold_target, None, 0.0)

    def _record(self, tel: Telemetry) -> None:
        if tel.pos_ned is None:
            return
        t = tel.time_boot_ms / 1000.0
        p, v = tel.pos_ned, tel.vel_ned
        self.metrics.write(
            {"t": t, "north": p[0], "east": p[1], "down": p[2], "vn": v[0], "ve": v[1],
             "vd": v[2], "mode": tel.mode.name if tel.mode else "", "armed": int(tel.armed),
             "phase": self.phase}
        )  # fmt: skip
        self.track.append((t, *p))

    # ---- phases (main thread) ------------------------------------------------------------
    def left(self) -> float:
        """Wall time left [s] (at least 1 s so the last wait still reports what it waited for)."""
        return max(1.0, self.t_end - time.monotonic())

    def step(self, phase: str, description: str) -> None:
        self.phase = phase
        self.bar.set_description(description)

    def done(self) -> None:
        self.bar.update()

    def connect_arm_takeoff(self, altitude: float) -> None:
        c, tel = self.client, self.tel
        self.step("connect", "connect: waiting for heartbeat, home and position")
        c.wait_ready(timeout=min(30.0, self.left()))
        self.done()
        self.step("arm", "arm")
        c.wait_until(lambda: tel.landed_state == 1, min(30.0, self.left()), "vehicle on ground")
        c.arm()
        self.done()
        self.step("takeoff", f"takeoff to {altitude:.0f} m")
        c.takeoff(altitude)
        c.wait_until(
            lambda: tel.pos_ned is not None and -tel.pos_ned[2] > altitude - 0.5,
            self.left(),
            f"altitude {altitude:.0f} m",
        )
        self.done()

    def offboard(self, altitude: float) -> None:
        """Stream a hold-position setpoint, then switch to OFFBOARD (PX4 needs the stream first)."""
        c, tel = self.client, self.tel
        self.step("offboard", "offboard")
        self.hold_target = np.array([tel.pos_ned[0], tel.pos_ned[1], -altitude])
        c.wait_message("LOCAL_POSITION_NED")
        c.wait_message("LOCAL_POSITION_NED")
        self.set_mode(FlightMode.OFFBOARD)
        self.done()

    def set_mode(self, mode: FlightMode) -> None:
        self.client.set_mode(mode)
        self.client.wait_until(lambda: self.tel.mode is mode, min(10.0, self.left()), mode.name)

    def land(self) -> None:
        self.step("land", "land")
        self.client.land()
        self.client.wait_until(lambda: not self.tel.armed, self.left(), "landing and disarm")
        self.done()

    def vehicle_time(self) -> float:
        return self.tel.time_boot_ms / 1000.0

    def close(self) -> np.ndarray:
        """Stop streaming; return the track (K, 4): t, north, east, down."""
        self.client.stream_offboard(None)
        self.bar.close()
        self.metrics.close()
        return np.array(self.track) if self.track else np.zeros((0, 4))
