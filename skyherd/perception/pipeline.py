"""The UAV's camera in a flight: at the camera rate, render → publish on Zenoh → detect → φ(s).

    rig = CameraRig(CameraParams(), n_ugv=3, params=CameraRigParams(renderer="fast"),
                    publisher=FramePublisher(session, "uav0", cam))
    ...
    out = rig.tick(clock.t, vehicle_state, ugv_states)   # None between camera frames
    if out is not None:
        phi = out.phi                                     # (8,) in [0, 1], see features.py

Time is the shared simulation clock's [s]; `uav` is anything with `pos_ned` and `quat`
(flight.state.VehicleState). The altitude feature is −pos_ned[2] (height above home).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyherd.groundsim.ugv import UGVModel, UGVStates
from skyherd.perception.camera import CameraParams
from skyherd.perception.detector import Detections, Detector, DetectorParams
from skyherd.perception.features import FeatureParams
from skyherd.perception.render_fast import FastRenderer


@dataclass(frozen=True)
class CameraRigParams:
    renderer: str = "fast"  # "fast" (OpenCV) or "bullet" (PyBullet, needs the GroundWorld)
    rate_hz: float = 10.0  # camera frames per simulated second


@dataclass(frozen=True)
class CameraTick:
    """One camera frame: t [s] sim time, frame (H, W, 3) RGB, detections, φ(s) (8,)."""

    t: float
    frame: np.ndarray
    detections: Detections
    phi: np.ndarray
    seq: int


class CameraRig:
    """Renders, optionally publishes, and perceives at `rate_hz` of simulation time."""

    def __init__(
        self,
        cam: CameraParams,
        n_ugv: int,
        params: CameraRigParams | None = None,
        model: UGVModel | None = None,
        world=None,
        publisher=None,
        detector_params: DetectorParams | None = None,
        feature_params: FeatureParams | None = None,
    ):
        self.cam = cam
        self.p = params if params is not None else CameraRigParams()
        if not self.p.rate_hz > 0:
            raise ValueError(f"rate_hz must be > 0, got {self.p.rate_hz}")
        model = model if model is not None else UGVModel()
        if self.p.renderer == "fast":
            self.renderer = FastRenderer(cam, model)
        elif self.p.renderer == "bullet":
            if world is None:
                raise ValueError("the bullet renderer needs the GroundWorld (world=...)")
            from skyherd.perception.render_bullet import BulletRenderer

            self.renderer = BulletRenderer(world, cam)
        else:
            raise ValueError(f"renderer must be 'fast' or 'bullet', got {self.p.renderer!r}")
        self.detector = Detector(cam, n_ugv, detector_params or DetectorParams(), feature_params)
        self.publisher = publisher
        self._next_t: float | None = None
        self.frames = 0
        self.bad_poses = 0  # ticks skipped because the UAV pose was not finite

    def due(self, t: float) -> bool:
        """Whether a frame is due at simulation time t [s]."""
        return self._next_t is None or t >= self._next_t - 1e-9

    def tick(self, t: float, uav, ugv_states: UGVStates) -> CameraTick | None:
        """A frame when one is due (else None): render, publish, detect, φ(s).

        A non-finite UAV pose produces no frame (None, counted in `bad_poses`): the consumer
        sees what a real camera link would give, a missing frame, and φ(s) says frame_ok = 0.
        """
        if not self.due(t):
            return None
        period = 1.0 / self.p.rate_hz
        self._next_t = (t if self._next_t is None else self._next_t) + period
        if self._next_t <= t:  # fell behind (a long pause): re-anchor, no burst
            self._next_t = t + period
        try:
            frame = self.renderer.render(uav, ugv_states)
        except ValueError:
            self.bad_poses += 1
            return None
        seq = self.frames
        if self.publisher is not None:
            seq = self.publisher.publish(t, uav.pos_ned, uav.quat, frame)
        det = self.detector.detect(frame)
        phi = self.detector.features(det, -float(uav.pos_ned[2]))
        self.frames += 1
        return CameraTick(t, frame, det, phi, seq)
