"""The world around an outside vehicle (`skyherd sim --follow ADDRESS`): a real autopilot flies on
its own physics (PX4 SIH, ArduPilot SITL, real hardware), and skyherd supplies the rest of the
world — the UGV team and the downward camera — from that vehicle's own telemetry.

The world listens on a second MAVLink link of the autopilot (PX4's ground-station port, an
ArduPilot serial port), asks for the streams it needs, and at every camera instant of the
autopilot's clock (`time_boot_ms`) renders the team from the vehicle's reported pose and publishes
the frame on Zenoh. Free-running by nature: an outside autopilot does not wait for anyone.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from flight.autopilot_api import FlightMode
from groundsim.ugv import UGVModel
from hil.autopilots import UnknownAutopilot
from hil.client import Telemetry, update_telemetry
from perception.render_fast import FastRenderer
from policy.groundair.params import TaskParams
from runio import CsvWriter, atomic_write_text
from world.sim import _during, level_camera_mount
from world.team import new_team, team_states, truth_row, ugv_columns

M = mavlink2


class FollowWorld:
    """UGV team + camera around the vehicle at `link` (a hil.link.MavlinkLink)."""

    def __init__(
        self,
        link,
        params,
        session=None,
        run_dir: Path | None = None,
        task: TaskParams | None = None,
        system_id: int = 1,
    ):
        from perception.transport import FramePublisher

        self.link, self.p = link, params
        self.system_id = system_id  # the followed autopilot's MAVLink system id
        self.task = task if task is not None else TaskParams()
        self.tel = Telemetry()
        self.team = new_team(params.scenario, params.seed, self.task.n_ugvs)
        self.team_t: float | None = None
        self._team_t0 = 0.0
        self.renderer = FastRenderer(self.task.camera, UGVModel())
        self.publisher = None
        if session is not None:
            self.publisher = FramePublisher(session, params.vehicle, self.task.camera,
                                            rng=np.random.default_rng(params.seed))  # fmt: skip
        self.run_dir = Path(run_dir) if run_dir is not None else None
        cols = ["t", "north", "east", "down", "mode", "armed", "team_t"]
        cols += ugv_columns(self.task.n_ugvs)
        self.truth = CsvWriter(self.run_dir / "world.csv", cols) if self.run_dir else None
        self._stop = threading.Event()
        self.frames = 0
        self.error = ""

    def stop(self) -> None:
        self._stop.set()

    def run(self, duration_s: float | None = None) -> dict:
        """Follow until `stop()` (or `duration_s` of the vehicle's time after the first sample)."""
        period = 1.0 / self.p.camera_hz
        t_first: float | None = None
        next_t: float | None = None
        asked = -1e9
        wall0 = time.monotonic()
        while not self._stop.is_set():
            for msg in self.link.recv(0.05):
                if msg.get_srcSystem() != self.system_id or msg.get_srcComponent() != 1:
                    continue  # another vehicle on a shared ground-station port (14550)
                try:
                    update_telemetry(self.tel, msg)
                except UnknownAutopilot as e:
                    self.error = str(e)
                    return self._stats(wall0)
            now = time.monotonic()
            if self.tel.profile is not None and now - asked > 5.0:  # ArduPilot: ask for streams
                asked = now
                for msg_id, hz in self.tel.profile.stream_requests():
                    self.link.send(M.MAVLink_command_long_message(1, 1, M.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                                                  msg_id, 1e6 / hz, 0, 0, 0, 0, 0))  # fmt: skip
            state = self.tel.vehicle_state()
            if state is None:
                continue
            t = self.tel.t
            t_first = t if t_first is None else t_first
            if duration_s is not None and t - t_first >= duration_s:
                break
            if (
                next_t is None or t < next_t - 10 * period
            ):  # first sample, or the autopilot rebooted
                next_t = t
            if t >= next_t:
                self._camera(t, state)
                next_t += period * max(1, int((t - next_t) / period) + 1)
        return self._stats(wall0)

    def _camera(self, t: float, state) -> None:
        if self.team_t is None:
            start = self.p.ugv_start
            go = self.tel.mode is FlightMode.OFFBOARD if start == "offboard" else t >= float(start)
            if go:
                self.team_t, self._team_t0 = 0.0, t
        elif t - self._team_t0 > self.team_t:
            self.team.step(t - self._team_t0 - self.team_t)
            self.team_t = t - self._team_t0
        ugvs = team_states(self.team)
        uav = level_camera_mount(state)
        # --cut-camera windows count the vehicle's clock here (a fallback drill on a real autopilot)
        if self.publisher is not None and not _during(self.p.camera_losses, t):
            try:
                image = self.renderer.render(uav, ugvs)
            except ValueError:
                return
            self.publisher.publish(t, uav.pos_ned, uav.quat, image)
            self.frames += 1
        if self.truth is not None:
            row = truth_row(round(t, 6), state.pos_ned, ugvs, mode=self.tel.mode_name, armed=int(self.tel.armed),
                            team_t="" if self.team_t is None else round(self.team_t, 6))  # fmt: skip
            self.truth.write(row)

    def _stats(self, wall0: float) -> dict:
        stats = {"followed": True, "frames": self.frames, "wall_s": time.monotonic() - wall0,
                 "vehicle_t_s": self.tel.t, "autopilot": self.tel.profile.name if self.tel.profile else None,
                 "error": self.error}  # fmt: skip
        if self.run_dir is not None:
            atomic_write_text(self.run_dir / "sim_stats.json", json.dumps(stats, indent=2) + "\n")
        return stats

    def close(self) -> None:
        if self.truth is not None:
            self.truth.close()
        if self.publisher is not None:
            self.publisher.close()
        self.link.close()
