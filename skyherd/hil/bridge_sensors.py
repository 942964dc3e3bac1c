"""What a simulated autopilot's sensors read, from skyherd's true vehicle state.

Shared by the PX4 simulator interface (which sends IMU, magnetometer, barometer and GPS)
and the ArduPilot JSON backend (which sends the IMU only: ArduPilot models the other
sensors itself from position and attitude).

- IMU: the model's specific force (accelerometer, body FRD, includes ground contact) and
  body rates (gyro), plus white noise.
- Magnetometer: the Earth's field at home from the World Magnetic Model 2025 (pygeomag,
  the WGS-84 model NOAA publishes), constant over the flying area, rotated into the body:
  m_b = Rᵀ m_ned [gauss]. A fixed field can be given instead (`MagField`).
- Barometer: the ICAO standard atmosphere (troposphere, ICAO Doc 7488 eq. for p(h)):
  p = p0 (1 − L h / T0)^(g M / (R L)),  T = T0 − L h,  h = altitude AMSL [m].
- Noise: zero-mean Gaussian, drawn in blocks from one seeded numpy Generator (so a run is
  reproducible and no array is allocated per step).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from skyherd.flight.geo import Home

P0_PA = 101325.0  # sea-level pressure [Pa]
T0_K = 288.15  # sea-level temperature [K]
LAPSE_K_PER_M = 0.0065  # tropospheric lapse rate L [K/m]
BARO_EXPONENT = 5.25588  # g M / (R L) [-]
GAUSS_PER_NT = 1e-5  # [gauss/nT]
WMM_EPOCH_YEAR = 2026.0  # decimal year the field is evaluated at (fixed: reproducible)


def isa_pressure_pa(alt_amsl_m: float) -> float:
    """Static pressure [Pa] at an altitude AMSL [m] in the standard atmosphere."""
    return P0_PA * (1.0 - LAPSE_K_PER_M * alt_amsl_m / T0_K) ** BARO_EXPONENT


def isa_temperature_c(alt_amsl_m: float) -> float:
    """Static temperature [°C] at an altitude AMSL [m] in the standard atmosphere."""
    return T0_K - LAPSE_K_PER_M * alt_amsl_m - 273.15


@dataclass(frozen=True)
class MagField:
    """The Earth's magnetic field at home, NED [gauss]."""

    ned_gauss: tuple[float, float, float]

    @staticmethod
    def wmm(home: Home, year: float = WMM_EPOCH_YEAR) -> MagField:
        """The World Magnetic Model 2025 at home's latitude, longitude and altitude."""
        from pygeomag import GeoMag

        r = GeoMag(coefficients_file="wmm/WMM_2025.COF").calculate(
            glat=home.lat_deg, glon=home.lon_deg, alt=home.alt_m / 1000.0, time=year
        )
        return MagField((r.x * GAUSS_PER_NT, r.y * GAUSS_PER_NT, r.z * GAUSS_PER_NT))

    @property
    def declination_rad(self) -> float:
        return math.atan2(self.ned_gauss[1], self.ned_gauss[0])

    @property
    def inclination_rad(self) -> float:
        n, e, d = self.ned_gauss
        return math.atan2(d, math.hypot(n, e))


@dataclass(frozen=True)
class SensorNoise:
    """Standard deviations of white sensor noise (0 turns a channel's noise off)."""

    accel: float = 0.02  # [m/s^2]
    gyro: float = 0.002  # [rad/s]
    mag: float = 0.0005  # [gauss]
    baro: float = 1.0  # [Pa] (about 8 cm)
    gps_pos: float = 0.0  # [m] per axis
    gps_vel: float = 0.0  # [m/s] per axis

    def __post_init__(self) -> None:
        vals = [self.accel, self.gyro, self.mag, self.baro, self.gps_pos, self.gps_vel]
        if not all(math.isfinite(v) and v >= 0 for v in vals):
            raise ValueError(f"sensor noise must be finite and >= 0: {self}")


# one noise row: accel(3) gyro(3) mag(3) baro(1) gps_pos(3) gps_vel(3)
N_NOISE = 16


@dataclass
class NoiseBlock:
    """Pre-scaled Gaussian noise, one row per sensor frame, refilled in blocks."""

    noise: SensorNoise
    seed: int = 0
    rows: int = 4096
    _rng: np.random.Generator = field(init=False)
    _block: np.ndarray = field(init=False)
    _i: int = field(init=False)

    def __post_init__(self) -> None:
        n = self.noise
        self._scale = np.array(
            [n.accel] * 3
            + [n.gyro] * 3
            + [n.mag] * 3
            + [n.baro]
            + [n.gps_pos] * 3
            + [n.gps_vel] * 3
        )
        self.reset()

    def reset(self) -> None:
        self._rng = np.random.default_rng(self.seed)
        self._block = np.empty((self.rows, N_NOISE))
        self._i = self.rows

    def next_row(self) -> list[float]:
        """The next row of noise as Python floats (accel, gyro, mag, baro, gps pos, gps vel)."""
        if self._i >= self.rows:
            self._rng.standard_normal(out=self._block)
            self._block *= self._scale
            self._i = 0
        row = self._block[self._i].tolist()
        self._i += 1
        return row


def body_from_ned(quat, v: tuple[float, float, float]) -> tuple[float, float, float]:
    """Rotate a NED vector into body FRD: v_b = q* ⊗ v ⊗ q for the body → NED quaternion q.

    With u = −(x, y, z) (the conjugate's vector part): t = 2 u × v, v_b = v + w t + u × t.
    """
    w, ux, uy, uz = quat[0], -quat[1], -quat[2], -quat[3]
    vx, vy, vz = v
    tx = 2.0 * (uy * vz - uz * vy)
    ty = 2.0 * (uz * vx - ux * vz)
    tz = 2.0 * (ux * vy - uy * vx)
    return (
        vx + w * tx + (uy * tz - uz * ty),
        vy + w * ty + (uz * tx - ux * tz),
        vz + w * tz + (ux * ty - uy * tx),
    )
