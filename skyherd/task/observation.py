"""The policy's observation (14,) float32: the one definition flown by the companion and trained
on by the learners (the table is in policy.groundair.env's docstring).

0–7 φ(s) (perception.features), 8–10 the UAV velocity 0.5 + v / (2·v_max), 11–13 Δφ of the
centre and spread since the last step, 0.5 + 5·Δ; all clipped to [0, 1].
"""

from __future__ import annotations

import numpy as np

from skyherd.task.params import TaskParams

OBS_DIM = 14


def make_observation(phi, phi_prev, vel_ned, task: TaskParams) -> np.ndarray:
    """Observation (14,) float32 from φ (8,) now, φ at the previous step (None at the start) and
    the UAV velocity (north, east, down) [m/s]. The one definition used in training and in flight.
    """
    prev = phi_prev if phi_prev is not None else phi
    both = phi[4] > 0 and prev[4] > 0
    u = task.uav
    vm = (u.v_xy_mps, u.v_xy_mps, max(u.v_up_mps, u.v_down_mps))
    o = [float(x) for x in phi[:8]]
    o += [min(max(0.5 + float(v) / (2 * m), 0.0), 1.0) for v, m in zip(vel_ned, vm)]
    for j in (0, 1, 2):
        d = (phi[j] - prev[j]) if both else 0.0
        o.append(min(max(0.5 + 5.0 * d, 0.0), 1.0))
    return np.array(o, dtype=np.float32)
