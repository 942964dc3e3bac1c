"""The UAV's downward pinhole camera: world NED point → pixel, and the ground footprint.

This projection is the one geometry every consumer shares: the fast OpenCV renderer, the
PyBullet renderer (whose view/projection matrices are built from it), the detector's ground
truth and the fast training environment.

Frames
------
world   local NED about home [m]; the ground is the plane down = 0.
body    FRD, attitude quaternion (w, x, y, z) body → NED.
camera  optical frame: x right in the image, y down in the image, z along the optical axis.
        Mounted looking along body +z (down) with the image top towards body forward:
        x_cam = body y (right), y_cam = −body x (backward), z_cam = body z (down).
        An optional mount pitch tilts the optical axis forward (about body y).
pixel   (u, v) [px], u to the right, v down; integer (u, v) is the CENTRE of pixel
        (column u, row v) (OpenCV's convention), so the image centre is ((W−1)/2, (H−1)/2).

Pinhole model: u = fx·x/z + cx, v = fy·y/z + cy, square pixels (fx = fy).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from skyherd.flight.frames import quat_to_dcm

# Camera axes expressed in body FRD axes (columns = x_cam, y_cam, z_cam), level mount.
_R_BODY_FROM_CAM_DOWN = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class CameraParams:
    """Intrinsics and mounting of the downward camera.

    Defaults (320×240, 70° horizontal field of view): at 30 m the view is 42 m × 31.5 m on
    the ground, 7.6 px/m, so a 1.0 m UGV top marker covers about 8×8 px — large enough that
    its centroid is found to well under a pixel and separate UGVs stay separate blobs, while
    the view is wide enough to keep a spread-out group in frame. See docs/perception.md.
    """

    width_px: int = 320  # image width [px]
    height_px: int = 240  # image height [px]
    hfov_rad: float = math.radians(70.0)  # horizontal field of view [rad]
    mount_pitch_rad: float = 0.0  # optical axis tilted forward from straight down [rad]
    mount_offset_frd: tuple[float, float, float] = (0.0, 0.0, 0.1)  # lens in body FRD [m]
    near_m: float = 0.1  # near clip for renderers [m]
    far_m: float = 500.0  # far clip for renderers [m]

    def __post_init__(self) -> None:
        if self.width_px < 8 or self.height_px < 8:
            raise ValueError(f"image too small: {self.width_px}x{self.height_px}")
        if not (0.0 < self.hfov_rad < math.pi):
            raise ValueError(f"hfov_rad must be in (0, pi), got {self.hfov_rad}")

    @cached_property
    def fx(self) -> float:
        """Focal length [px] (= fy)."""
        return 0.5 * self.width_px / math.tan(0.5 * self.hfov_rad)

    @cached_property
    def cx(self) -> float:
        """Principal point u [px] (image centre)."""
        return 0.5 * (self.width_px - 1)

    @cached_property
    def cy(self) -> float:
        """Principal point v [px] (image centre)."""
        return 0.5 * (self.height_px - 1)

    @property
    def vfov_rad(self) -> float:
        """Vertical field of view [rad]."""
        return 2.0 * math.atan(0.5 * self.height_px / self.fx)

    @cached_property
    def centre_px(self) -> np.ndarray:
        """Image centre (cx, cy) [px], shape (2,)."""
        return np.array([self.cx, self.cy])

    @cached_property
    def K(self) -> np.ndarray:
        """Intrinsic matrix (3, 3)."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fx, self.cy], [0.0, 0.0, 1.0]])

    @cached_property
    def r_body_from_cam(self) -> np.ndarray:
        """Rotation (3, 3): camera optical axes → body FRD axes, including the mount pitch."""
        c, s = math.cos(self.mount_pitch_rad), math.sin(self.mount_pitch_rad)
        # Tilt the down-looking axis towards body forward: rotation about body y by +pitch.
        r_tilt = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        return r_tilt @ _R_BODY_FROM_CAM_DOWN

    def gsd_m_per_px(self, altitude_m: float) -> float:
        """Ground sample distance [m/px] looking straight down from `altitude_m`."""
        return altitude_m / self.fx


@dataclass(frozen=True)
class UAVPose:
    """Where the UAV is: position (3,) NED [m] and attitude (w, x, y, z) body FRD → NED.

    Anything with `pos_ned` and `quat` (flight.state.VehicleState) serves as well.
    """

    pos_ned: np.ndarray
    quat: np.ndarray


@dataclass(frozen=True)
class CameraPose:
    """Camera pose in the world: position of the lens (3,) NED [m] and R (3, 3) camera → NED."""

    pos_ned: np.ndarray
    r_world_from_cam: np.ndarray


def check_pose(uav_pos_ned: np.ndarray, uav_quat: np.ndarray) -> None:
    """Raise ValueError unless the position (3,) and quaternion (4,) are finite and |q| is
    within [0.5, 1.5] (telemetry rounding is normalised away by `camera_pose`)."""
    p, q = np.asarray(uav_pos_ned, dtype=float), np.asarray(uav_quat, dtype=float)
    if p.shape != (3,) or q.shape != (4,) or not (np.isfinite(p).all() and np.isfinite(q).all()):
        raise ValueError(f"UAV pose must be a finite (3,) position and (4,) quaternion: {p}, {q}")
    if not 0.25 <= float(q @ q) <= 2.25:
        raise ValueError(f"UAV quaternion is far from unit length: {q}")


def camera_pose(cam: CameraParams, uav_pos_ned: np.ndarray, uav_quat: np.ndarray) -> CameraPose:
    """The camera's pose from the UAV's position (3,) NED [m] and attitude (w, x, y, z)
    (normalised here)."""
    q = np.asarray(uav_quat, dtype=float)
    r_wb = quat_to_dcm(q / math.sqrt(float(q @ q)))
    pos = np.asarray(uav_pos_ned, dtype=float) + r_wb @ np.asarray(cam.mount_offset_frd)
    return CameraPose(pos, r_wb @ cam.r_body_from_cam)


def project(cam: CameraParams, pose: CameraPose, points_ned: np.ndarray) -> tuple:
    """World points → pixels.

    points_ned (..., 3) NED [m]. Returns (uv (..., 2) [px], depth (...,) [m] along the optical
    axis). Points behind the camera (depth <= 0) get uv = NaN.
    """
    p = (np.asarray(points_ned, dtype=float) - pose.pos_ned) @ pose.r_world_from_cam
    z = p[..., 2]
    if (z > 1e-9).all():  # the usual case, kept lean for the fast training path
        return p[..., :2] * (cam.fx / z)[..., None] + cam.centre_px, z
    with np.errstate(divide="ignore", invalid="ignore"):
        zi = np.where(z > 1e-9, cam.fx / z, np.nan)
    return p[..., :2] * zi[..., None] + cam.centre_px, z


def in_image(cam: CameraParams, uv: np.ndarray, margin_px: float = 0.0) -> np.ndarray:
    """Boolean (...,): pixel inside the image by at least `margin_px` (NaN → False)."""
    lo = -0.5 + margin_px
    hi = np.array([cam.width_px - 0.5 - margin_px, cam.height_px - 0.5 - margin_px])
    return ((uv >= lo) & (uv <= hi)).all(axis=-1)  # NaN compares False


def pixel_ray_ned(cam: CameraParams, pose: CameraPose, uv: np.ndarray) -> np.ndarray:
    """Unit ray directions (..., 3) in NED through pixels uv (..., 2)."""
    uv = np.asarray(uv, dtype=float)
    d = np.stack(
        [(uv[..., 0] - cam.cx) / cam.fx, (uv[..., 1] - cam.cy) / cam.fx, np.ones(uv.shape[:-1])],
        axis=-1,
    )
    d = d @ pose.r_world_from_cam.T
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def backproject_to_ground(
    cam: CameraParams, pose: CameraPose, uv: np.ndarray, ground_down_m: float = 0.0
) -> np.ndarray:
    """Pixels (..., 2) → points (..., 3) NED on the plane down = ground_down_m.

    Rays that do not reach the ground (at or above the horizon) give NaN.
    """
    d = pixel_ray_ned(cam, pose, uv)
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (ground_down_m - pose.pos_ned[2]) / d[..., 2]
    s = np.where(s > 0, s, np.nan)
    return pose.pos_ned + d * s[..., None]


def footprint_ned(cam: CameraParams, pose: CameraPose, max_range_m: float = 1000.0) -> np.ndarray:
    """Ground footprint: the image corners' rays on the ground, (4, 2) north/east [m].

    Corner order: top-left, top-right, bottom-right, bottom-left (image order). A corner whose
    ray misses the ground (camera tilted past the horizon) is placed `max_range_m` out along the
    ray's horizontal direction, so the polygon stays finite.
    """
    w, h = cam.width_px, cam.height_px
    corners = np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])
    d = pixel_ray_ned(cam, pose, corners)
    out = np.empty((4, 2))
    for i in range(4):
        s = -pose.pos_ned[2] / d[i, 2] if d[i, 2] > 1e-9 else math.inf
        if s * math.hypot(d[i, 0], d[i, 1]) > max_range_m or not math.isfinite(s):
            hd = d[i, :2] / max(math.hypot(d[i, 0], d[i, 1]), 1e-12)
            out[i] = pose.pos_ned[:2] + hd * max_range_m
        else:
            out[i] = pose.pos_ned[:2] + d[i, :2] * s
    return out
