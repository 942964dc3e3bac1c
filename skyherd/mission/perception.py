"""The companion's perception: the frame received over Zenoh → detector → φ(s) → observation.

The frame detected on is the frame received (its bytes, as they came off the wire); φ's
altitude is the autopilot's estimate at the frame's capture time (mission.onboard.CameraFrame),
never the simulator's truth. A corrupt or lost frame leaves φ(s) as it was and the camera's
last-good time where it was, so the safety net sees the camera go stale exactly as a real link
would show it.
"""

from __future__ import annotations

import numpy as np

from skyherd.mission.onboard import CameraFrame
from skyherd.perception.detector import Detector
from skyherd.perception.sheet import FrameSample
from skyherd.task.observation import make_observation
from skyherd.task.params import TaskParams


class Perception:
    def __init__(self, task: TaskParams):
        self.task = task
        self.detector = Detector(task.camera, task.n_ugvs)
        self.phi = self.detector.features(None, 0.0)  # no frame yet: frame_ok = 0
        self.phi_prev: np.ndarray | None = None  # φ at the previous decision
        self.camera_t: float | None = None  # tick time of the last good frame [s]
        self.counts = {"ok": 0, "corrupt": 0, "lost": 0}
        self.strip = FrameSample()  # frames.png's frames (perception.sheet)
        self.last = None  # (CameraFrame, Detections) of the last good frame (mission.search)

    def on_frame(self, t: float, frame: CameraFrame | None, status: str, phase: str = "") -> None:
        self.counts[status] = self.counts.get(status, 0) + 1
        if frame is None:
            return
        det = self.detector.detect(frame.image)
        self.last = (frame, det)
        self.phi = self.detector.features(det, frame.altitude_m)
        self.camera_t = t
        self.strip.add(t, frame.image, det, frame.altitude_m, phase)

    def observation(self, state) -> np.ndarray:
        """(φ, velocity, Δφ since the last decision), built by the training environment's code."""
        return make_observation(self.phi, self.phi_prev, state.vel_ned, self.task)

    def decided(self) -> None:
        self.phi_prev = self.phi.copy()  # Δφ is taken over one decision period, as in training
