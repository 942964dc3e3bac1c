"""The phases every mission shares, flown through `VehicleClient` with the recipes of the
autopilot it found (hil/autopilots.py): connect, take off, hand over to the AI's mode, land,
and leave the vehicle disarmed in a normal mode. Telemetry is recorded to metrics.csv on every
position sample, and a mission supplies the offboard setpoint for each sample.

When the autopilot changes mode on its own (failsafe, ground station, pilot) the session
yields: no further mode request or setpoint, and the landing is the autopilot's.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable

import numpy as np
from tqdm import tqdm

from flight.autopilot_api import FlightMode
from hil.client import ClientTimeout, CommandError, Telemetry, VehicleClient, Yielded
from runio import atomic_write_text
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
        self.landed = False
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
        c = self.client
        self.step("connect", "connect: waiting for heartbeat, position and home")
        c.wait_ready(timeout=self.left())
        p = c.profile
        self.bar.write(f"skyherd fly: {p.name} {p.version}".rstrip() + f" ({p.vehicle})")
        self.done()
        self.step("arm", f"arm and take off the {p.name} way")
        steps = p.takeoff_steps(altitude, c.home_amsl())
        self.done()
        self.step("takeoff", f"takeoff to {altitude:.0f} m")
        c.run_steps(steps, self.left(), authority=False)
        self.done()

    def offboard(self, altitude: float) -> None:
        """Stream a hold-position setpoint, then switch to the AI's mode (OFFBOARD / GUIDED)."""
        c, tel = self.client, self.tel
        self.step("offboard", f"hand-over to {c.profile.ai_mode.name}")
        self.hold_target = np.array([tel.pos_ned[0], tel.pos_ned[1], -altitude])
        c.run_steps(c.profile.handover_steps(), self.left(), hold_ned=self.hold_target)
        self.done()

    def set_mode(self, mode: FlightMode) -> None:
        """Request `mode` and wait until the heartbeat shows it; Yielded once the autopilot
        has taken over (never switch back from its failsafe)."""
        self.client.set_mode(mode)
        self.client.wait_until(
            lambda: self.tel.mode is mode, min(10.0, self.left()), mode.name,
            vehicle_s=self.client.options.mode_wait_s,
        )  # fmt: skip

    def land(self) -> None:
        """The profile's landing, then its end: disarmed, streaming stopped, a normal mode."""
        c = self.client
        self.step("land", "land")
        if self.client.yielded:
            raise Yielded(self.client.yielded)
        c.run_steps(c.profile.land_steps(), self.left())
        self.landed = not self.tel.armed
        self._end()
        self.done()

    def _end(self) -> None:
        try:
            self.client.run_steps(self.client.profile.end_steps(), self.left())
        except (ClientTimeout, CommandError) as e:
            self.bar.write(f"skyherd fly: after the landing: {e}")

    def vehicle_time(self) -> float:
        return self.tel.time_boot_ms / 1000.0

    def close(self) -> np.ndarray:
        """Stop streaming and leave the vehicle safe; return the track (K, 4): t, north, east,
        down. A mission that ended in the air lands the profile's way; when the autopilot has
        taken over, its landing is waited for (not commanded)."""
        c = self.client
        c.stop_setpoints()
        if c.profile is not None and self.tel.armed and not self.landed:
            self._leave_safe()
        c.stream_offboard(None)
        self._write_autopilot_log()
        self.bar.close()
        self.metrics.close()
        return np.array(self.track) if self.track else np.zeros((0, 4))

    def _write_autopilot_log(self) -> None:
        """autopilot.json beside metrics.csv: which autopilot, its mode changes (requested by
        skyherd or its own), what it said, and whether skyherd yielded to it."""
        tel, p = self.tel, self.client.profile
        log = {
            "autopilot": None if p is None else {"name": p.name, "version": p.version,
                                                 "vehicle": p.vehicle},
            "modes": [{"t": round(t, 3), "mode": name, "requested": req} for t, name, req in tel.modes],
            "statustexts": [{"t": round(t, 3), "severity": sev, "text": x}
                            for t, sev, x in tel.statustexts],
            "unrequested_mode_changes": tel.unrequested_mode_change,
            "yielded": tel.yielded,
            "setpoints_sent": self.client.setpoints_sent,
        }  # fmt: skip
        try:
            atomic_write_text(
                self.metrics.path.with_name("autopilot.json"), json.dumps(log, indent=1)
            )
        except OSError as e:
            self.bar.write(f"skyherd fly: could not write autopilot.json: {e}")

    def _leave_safe(self) -> None:
        c, tel = self.client, self.tel
        try:
            if c.yielded:
                if tel.mode not in (FlightMode.LAND, FlightMode.RTL):
                    self.bar.write(f"skyherd fly: {tel.yielded}; it keeps the vehicle in "
                                   f"{tel.mode_name}")  # fmt: skip
                    return  # a hold or a pilot's mode: nothing to wait for
                self.bar.write(f"skyherd fly: {tel.yielded}; waiting for it to land")
                c.wait_until(lambda: not tel.armed, self.left(), "the autopilot's landing",
                             vehicle_s=c.options.land_wait_s, interruptible=False)  # fmt: skip
                return
            if tel.landed_state == 1:  # still on the ground: nothing to land
                c.disarm()
                return
            self.bar.write(f"skyherd fly: landing the {c.profile.name} way after the abort")
            c.interrupt = ""
            c.run_steps(c.profile.land_steps(), self.left())
            self._end()
        except (ClientTimeout, CommandError) as e:
            self.bar.write(f"skyherd fly: could not land after the abort: {e}")
