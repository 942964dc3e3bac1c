"""The vehicle state every layer agrees on."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from skyherd.flight.frames import quat_to_euler


@dataclass(frozen=True)
class VehicleState:
    """Rigid-body state at simulation time `t` [s].

    pos_ned   (3,) position about home [m], NED
    vel_ned   (3,) velocity [m/s], NED
    quat      (4,) attitude (w, x, y, z), body FRD → NED
    omega_frd (3,) angular rate [rad/s], body FRD
    accel_frd (3,) specific force [m/s^2], body FRD (what an accelerometer reads; -g·z at rest)
    on_ground true while resting on the ground
    """

    t: float
    pos_ned: np.ndarray
    vel_ned: np.ndarray
    quat: np.ndarray
    omega_frd: np.ndarray
    accel_frd: np.ndarray
    on_ground: bool

    @property
    def euler(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) [rad], ZYX."""
        return quat_to_euler(self.quat)

    @property
    def altitude(self) -> float:
        """Height above home [m] (= -down)."""
        return -float(self.pos_ned[2])
