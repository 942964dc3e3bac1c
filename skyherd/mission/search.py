"""`--lost-ugv-search`: the ground-air pilot with the search for a lost UGV (policy.search.lost)
in front of it, as flown by `skyherd fly`.

Onboard, what the search needs comes from the frames alone: each detection's identity is its
marker's colour (the nearest of groundsim.ugv.MARKER_COLOURS to the pixels at the blob's
centroid) and its ground position is the centroid back-projected through the camera's pose at
capture (the autopilot's estimate composed with the level gimbal: mission.onboard.CameraFrame)
onto the markers' plane. While every UGV ever seen is in view the base pilot (the learned
policy or the PID follower) flies; when one is lost, `LostSearch.search_command` gives the
velocity (dead reckoning, climbing toward the ceiling, expanding square), rate-limited around
the present velocity to what the envelope's acceleration rows accept (as the landing's
DescentPilot is), and the same SafetyNet certifies it. The decision's explanation names the
search's phase and the UGVs in view.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyherd.flight.autopilot_api import Setpoint
from skyherd.groundsim.ugv import MARKER_COLOURS, UGVModel
from skyherd.mission.pilots import Observation, Pilot, Proposal
from skyherd.perception.camera import backproject_to_ground
from skyherd.policy.search.lost import LostSearch


def identify(image: np.ndarray, centroids_px: np.ndarray, n_ugvs: int) -> list[int]:
    """The UGV id of each detection: the nearest marker colour (RGB) of the first n_ugvs to
    the mean of the 3 × 3 pixels around the centroid; -1 when none is within 120 (RGB units)."""
    h, w = image.shape[:2]
    cols = np.array(MARKER_COLOURS[:n_ugvs], dtype=float)
    out = []
    for u, v in np.asarray(centroids_px, dtype=float).reshape(-1, 2):
        x, y = int(round(u)), int(round(v))
        patch = image[max(y - 1, 0) : min(y + 2, h), max(x - 1, 0) : min(x + 2, w)].reshape(-1, 3)
        d = np.linalg.norm(cols - patch.mean(axis=0), axis=1)
        out.append(int(np.argmin(d)) if d.min() < 120.0 else -1)
    return out


def sightings(frame, det, cam, n_ugvs: int, mount: str = "level") -> dict[int, np.ndarray]:
    """{UGV id: (north, east) [m]} of one frame's detections (empty without a pose estimate)."""
    pose = frame.camera_pose(cam, mount)
    if pose is None or len(det.centroids_px) == 0:
        return {}
    ground = backproject_to_ground(cam, pose, det.centroids_px, -UGVModel().marker_top_m)
    out = {}
    for i, g in zip(identify(frame.image, det.centroids_px, n_ugvs), ground):
        if i >= 0 and np.all(np.isfinite(g)):
            out[i] = g[:2].copy()
    return out


@dataclass
class SearchPilot:
    """`base` while all are in view; the search's velocity while one is lost."""

    base: Pilot
    perception: object  # mission.perception.Perception (its last frame and detections)
    search: LostSearch
    limits: object  # safety.envelope.Limits of the flight's envelope
    tau_s: float  # the envelope's velocity-loop time constant [s]

    @property
    def name(self) -> str:
        return self.base.name

    @property
    def done(self) -> bool:
        return bool(getattr(self.base, "done", False))

    def propose(self, o: Observation) -> Proposal:
        from skyherd.flight.geo import GRAVITY
        from skyherd.safety.drills import slew

        last = self.perception.last
        seen = (
            {}
            if last is None
            else sightings(*last, self.perception.task.camera, self.perception.task.n_ugvs)
        )
        cmd = self.search.search_command(o.t, o.state.pos_ned, seen)
        if cmd is None:
            return self.base.propose(o)
        lim = self.limits
        a_h = min(lim.accel_h_mps2, GRAVITY * np.tan(lim.tilt_cmd_rad))
        u = slew(cmd, o.state.vel_ned, 0.8 * a_h * self.tau_s, 0.8 * lim.accel_v_mps2 * self.tau_s)
        s = self.search
        why = {"module": "search", "reason": f"{s.mode}: UGV {s.quarry} lost",
               "concepts": {"seen": sorted(seen), "quarry": s.quarry}}  # fmt: skip
        return Proposal(Setpoint(vel_ned=u, yaw=0.0), -1, why)
