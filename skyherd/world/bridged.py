"""The world around a real autopilot that flies on skyherd's physics (`skyherd sim --autopilot
px4|ardupilot`): PX4 (`none_iris`, TCP 4560+N) or ArduPilot (`--model JSON`, UDP 9002+10N) steps
the bridge's quadrotor in its own lockstep (hil/px4_sim.py, hil/ardupilot_json.py); at every camera
instant of that simulation clock the world's `Scene` (world/scene.py) renders the UGV team from the
bridge's true pose and publishes the frame, the UGV states and the clock. The companion talks MAVLink to the autopilot itself (free-running: the
autopilot paces itself), so `skyherd fly --connect` flies it.
"""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

from skyherd.runio import atomic_write_text
from skyherd.task.params import TaskParams
from skyherd.world.scene import Scene


class BridgedWorld:
    """UGV team + camera around `bridge` (hil.bridge_select.make_bridge)."""

    def __init__(self, bridge, params, session=None, run_dir: Path | None = None,
                 key: bytes | None = None):  # fmt: skip
        """key: the flight key: camera frames, UGV states and the clock signed."""
        self.bridge, self.p = bridge, params
        self.task = TaskParams()
        self.scene = Scene(params, self.task, session, run_dir, key)
        self.scene.listen_for_hand_over(session)
        self.run_dir = self.scene.run_dir
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    def companion_gone(self, why: str) -> None:
        """Nothing flies alone here: the autopilot is stepped only while it asks for frames, so
        the world stops (world.protocol.SimWorld)."""
        self.stop()

    def parent_died(self, why: str) -> None:
        self.companion_gone(why)

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
        stats = {"bridged": True, "frames": self.scene.frames, "sim_s": self.bridge.t,
                 "render_failures": self.scene.render_failures,
                 "camera_loss_frames": self.scene.camera_dropped,
                 "wall_s": time.monotonic() - wall0, "bridge": str(getattr(self.bridge, "stats", ""))}  # fmt: skip
        stats["real_time_factor"] = stats["sim_s"] / stats["wall_s"] if stats["wall_s"] > 0 else 0.0
        if self.run_dir is not None:
            atomic_write_text(self.run_dir / "sim_stats.json", json.dumps(stats, indent=2) + "\n")
        return stats

    def _camera(self, t: float) -> None:
        # The bridge carries no flight mode: a team waiting for "offboard" starts at the
        # companion's first decision (Scene.listen_for_hand_over); mode and arming are not in
        # world.csv.
        self.scene.instant(t, self.bridge.state, "", None, offboard=self.scene.handed_over)

    def close(self) -> None:
        self.scene.close()
        self.bridge.close()
