"""A roll/pitch-stabilised pan–tilt gimbal that points the camera at a ground target.

The camera of `perception.camera` is fixed to the body (looking down). A fixed-wing banks
about 20–25° in its orbit, so a body-fixed camera would swing its view across the ground once a
lap. Fixed-wing ISR aircraft carry an inertially stabilised gimbal instead: its orientation
depends only on the line of sight, not on the aircraft's roll and pitch. This module computes
that orientation.

Camera axes (optical frame, as in perception.camera): z along the line of sight
l = (target − lens)/|target − lens| (NED), x = image right, horizontal: x = (d × l)/|d × l| with
d = (0, 0, 1) the down axis, and y = z × x (image down). The image is therefore roll-levelled
(the horizon stays horizontal), as a 2-axis pan/tilt gimbal gives. Looking straight down, where
d × l vanishes, the pan falls back to the aircraft's heading (image top = forward).

The renderers take a UAV pose (pos_ned, quat) and apply the body mount `r_body_from_cam`. The
gimbal is expressed through that interface as a *virtual body attitude* q_v with
R(q_v)·r_body_from_cam = R_world_from_cam, so every renderer, the detector and the Zenoh
publisher see the gimballed camera without change.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from skyherd.perception.camera import CameraParams

_DOWN = np.array([0.0, 0.0, 1.0])

# The zoomed gimbal camera: 320×240 like the quadrotor's, 20° horizontal field of view
# (f = 907 px): a 1 m marker spans ~3 px at ~190 m slant range, a 20 m team fits in 1/3 of H.
ORBIT_CAMERA = CameraParams(hfov_rad=math.radians(20.0), mount_offset_frd=(0.0, 0.0, 0.0))


@dataclass(frozen=True)
class GimbalParams:
    """Mechanical limits of the pan–tilt head."""

    tilt_min_rad: float = math.radians(5.0)  # least depression below the horizon [rad]
    tilt_max_rad: float = math.radians(90.0)  # straight down [rad]


@dataclass(frozen=True)
class GimbalPose:
    """Virtual UAV pose the renderers take: lens position (3,) NED [m], quaternion (w, x, y, z)
    whose body axes carry the camera mount to the gimballed orientation."""

    pos_ned: np.ndarray
    quat: np.ndarray
    tilt_rad: float  # depression of the line of sight below the horizon [rad]
    pan_rad: float  # azimuth of the line of sight, 0 = north, + east [rad]


def dcm_to_quat(r: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) of a rotation matrix (3, 3) (Shepperd's method)."""
    tr = r[0, 0] + r[1, 1] + r[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    elif r[0, 0] > r[1, 1] and r[0, 0] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
    elif r[1, 1] > r[2, 2]:
        s = 2.0 * math.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2])
        q = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1])
        q = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def look_at(
    lens_ned: np.ndarray, target_ned: np.ndarray, heading: float, p: GimbalParams = GimbalParams()
) -> tuple[np.ndarray, float, float]:
    """Camera → NED rotation (3, 3) looking from `lens_ned` (3,) at `target_ned` (3,) [m],
    tilt clamped to the gimbal's range; `heading` [rad] sets the pan when looking straight
    down. Returns (R_world_from_cam, tilt [rad], pan [rad]). Raises ValueError on non-finite
    input."""
    lens, tgt = np.asarray(lens_ned, dtype=float), np.asarray(target_ned, dtype=float)
    if not (np.isfinite(lens).all() and np.isfinite(tgt).all() and math.isfinite(heading)):
        raise ValueError(f"gimbal input must be finite: lens {lens}, target {tgt}, {heading}")
    d = tgt - lens
    horiz = math.hypot(d[0], d[1])
    pan = math.atan2(d[1], d[0]) if horiz > 1e-6 else heading
    tilt = math.atan2(d[2], horiz)  # depression, + below the horizon
    tilt = min(max(tilt, p.tilt_min_rad), p.tilt_max_rad)
    ct, st, cp, sp = math.cos(tilt), math.sin(tilt), math.cos(pan), math.sin(pan)
    z = np.array([ct * cp, ct * sp, st])  # line of sight
    x = np.array([-sp, cp, 0.0])  # image right: horizontal, (d × z) normalised
    y = np.cross(z, x)  # image down
    return np.column_stack([x, y, z]), tilt, pan


def gimbal_pose(
    cam: CameraParams,
    uav_pos_ned: np.ndarray,
    heading: float,
    target_ned: np.ndarray,
    p: GimbalParams = GimbalParams(),
) -> GimbalPose:
    """The virtual pose that renders the gimballed camera pointing at `target_ned` (3,).

    The gimbal sits at the UAV's reference point (the mount offset is ignored: a few cm against
    a slant range of ~200 m)."""
    pos = np.asarray(uav_pos_ned, dtype=float)
    r_wc, tilt, pan = look_at(pos, target_ned, heading, p)
    r_wb = r_wc @ cam.r_body_from_cam.T
    lens = pos - r_wb @ np.asarray(cam.mount_offset_frd)  # so camera_pose puts the lens at pos
    return GimbalPose(lens, dcm_to_quat(r_wb), tilt, pan)


def pointed_pose(cam: CameraParams, state, roi_ned: np.ndarray | None) -> GimbalPose:
    """The pan-tilt head of a vehicle in `state` (a VehicleState) pointed at the ROI, or straight
    down below the vehicle until a client has set one."""
    _, _, yaw = state.euler
    target = roi_ned if roi_ned is not None else np.array([*state.pos_ned[:2], 0.0])
    return gimbal_pose(cam, state.pos_ned, yaw, target)


def roi_ned(home, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> np.ndarray | None:
    """MAV_CMD_DO_SET_ROI_LOCATION's target (params 5-7) in local NED about `home`; None when the
    location is not a finite latitude/longitude (the command is then denied)."""
    from skyherd.flight.geo import geodetic_to_ned

    p = (lat_deg, lon_deg, alt_amsl_m)
    if home is None or not all(math.isfinite(x) for x in p) or abs(p[0]) > 90 or abs(p[1]) > 180:
        return None
    return geodetic_to_ned(home, *p)
