"""The world around a real autopilot that flies on skyherd's physics (`skyherd sim --autopilot
px4|ardupilot`): PX4 (`none_iris`, TCP 4560+N) or ArduPilot (`--model JSON`, UDP 9002+10N) steps
the bridge's quadrotor in its own lockstep (hil/px4_sim.py, hil/ardupilot_json.py); at every camera
instant of that simulation clock the world renders the UGV team from the bridge's true pose and
publishes the frame. The companion talks MAVLink to the autopilot itself (free-running: the
autopilot paces itself), so `skyherd fly --connect` flies it.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import numpy as np

from skyherd.groundsim.transport import UGVStatePublisher
from skyherd.groundsim.ugv import UGVModel
from skyherd.perception.render_fast import FastRenderer
from skyherd.runio import CsvWriter, atomic_write_text
from skyherd.task.params import TaskParams
from skyherd.world.sim import level_camera_mount
from skyherd.world.team import new_team, team_states, truth_row, ugv_columns


class BridgedWorld:
    """UGV team + camera around `bridge` (hil.bridge_select.make_bridge)."""

    def __init__(self, bridge, params, session=None, run_dir: Path | None = None,
                 key: bytes | None = None):  # fmt: skip
        """key: the flight key: camera frames and UGV states signed (perception, groundsim)."""
        from skyherd.perception.transport import FramePublisher

        self.bridge, self.p = bridge, params
        self.task = TaskParams()
        self.team = new_team(params.scenario, params.seed, self.task.n_ugvs)
        self.renderer = FastRenderer(self.task.camera, UGVModel())
        self.publisher = self.ugv_pub = None
        if session is not None:
            self.publisher = FramePublisher(session, params.vehicle, self.task.camera,
                                            mount="level",  # level_camera_mount below
                                            rng=np.random.default_rng(params.seed), key=key)  # fmt: skip
            self.ugv_pub = UGVStatePublisher(session, self.task.n_ugvs, key=key)
        self.run_dir = Path(run_dir) if run_dir is not None else None
        cols = ["t", "north", "east", "down"] + ugv_columns(self.task.n_ugvs)
        self.truth = CsvWriter(self.run_dir / "world.csv", cols) if self.run_dir else None
        self._stop = threading.Event()
        self.frames = 0
        self._t_team = 0.0

    def stop(self) -> None:
        self._stop.set()

    def run(self, duration_s: float | None = None) -> dict:
        """Serve the autopilot frame by frame until `stop()` (or `duration_s` of sim time)."""
        period = 1.0 / self.p.camera_hz
        next_t = 0.0
        wall0 = time.monotonic()
        self.bridge.open_port()
        accept = getattr(self.bridge, "accept", None)  # PX4 connects to us; ArduPilot just sends
        while accept is not None and not self._stop.is_set():
            if accept(0.5):
                break  # else PX4 has not started yet
        while not self._stop.is_set():
            if duration_s is not None and self.bridge.t >= duration_s:
                break
            if not self.bridge.step_once(0.5):
                continue  # the autopilot has not asked yet (booting) or paused
            t = self.bridge.t
            if t >= next_t - 1e-9:
                self._camera(t)
                next_t += period
        stats = {"bridged": True, "frames": self.frames, "sim_s": self.bridge.t,
                 "wall_s": time.monotonic() - wall0, "bridge": str(getattr(self.bridge, "stats", ""))}  # fmt: skip
        stats["real_time_factor"] = stats["sim_s"] / stats["wall_s"] if stats["wall_s"] > 0 else 0.0
        if self.run_dir is not None:
            atomic_write_text(self.run_dir / "sim_stats.json", json.dumps(stats, indent=2) + "\n")
        return stats

    def _camera(self, t: float) -> None:
        if t > self._t_team:  # the team drives from the start (no OFFBOARD to wait for here)
            self.team.step(t - self._t_team)
            self._t_team = t
        state = self.bridge.state
        ugvs = team_states(self.team)
        if self.publisher is not None:
            uav = level_camera_mount(state)
            try:
                image = self.renderer.render(uav, ugvs, self.publisher.frame_buffer())
            except ValueError:
                return
            self.publisher.publish(t, uav.pos_ned, uav.quat, image)
            self.ugv_pub.publish(t, ugvs)
            self.frames += 1
        if self.truth is not None:
            self.truth.write(truth_row(round(t, 6), state.pos_ned, ugvs))

    def close(self) -> None:
        if self.truth is not None:
            self.truth.close()
        for x in (self.publisher, self.ugv_pub):
            if x is not None:
                x.close()
        self.bridge.close()
