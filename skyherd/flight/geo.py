"""Geodetic ↔ local NED on a local tangent plane about home (WGS-84).

Degrees appear here only because MAVLink and users give positions in degrees.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WGS84_A = 6378137.0  # semi-major axis [m]
WGS84_F = 1.0 / 298.257223563  # flattening [-]
WGS84_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared [-]
GRAVITY = 9.80665  # standard gravity [m/s^2]


HOME_ALT_RANGE_M = (-500.0, 9000.0)  # a home's altitude AMSL a vehicle can be at [m]


def home_in_range(lat_deg: float, lon_deg: float, alt_m: float) -> bool:
    """A home's latitude, longitude [deg] and altitude AMSL [m] in range (NaN is not)."""
    lo, hi = HOME_ALT_RANGE_M
    return -90 <= lat_deg <= 90 and -180 <= lon_deg <= 180 and lo <= alt_m <= hi


@dataclass(frozen=True)
class Home:
    """Home position: latitude, longitude [deg], altitude AMSL [m], heading [rad]."""

    lat_deg: float = -35.363261
    lon_deg: float = 149.165230
    alt_m: float = 584.0
    heading_rad: float = 0.0

    @staticmethod
    def parse(text: str) -> Home:
        """Parse 'LAT,LON,ALT' (degrees, degrees, metres AMSL). Raises ValueError."""
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 3:
            raise ValueError(f"home must be LAT,LON,ALT, got {text!r}")
        lat, lon, alt = (float(p) for p in parts)
        if not home_in_range(lat, lon, alt):
            raise ValueError(f"home out of range: {text!r}")
        return Home(lat, lon, alt)


DEFAULT_HOME = Home()


def _radii(lat_rad: float) -> tuple[float, float]:
    """Meridian and prime-vertical radii of curvature [m] at a latitude."""
    s = math.sin(lat_rad)
    d = 1.0 - WGS84_E2 * s * s
    r_n = WGS84_A / math.sqrt(d)
    r_m = WGS84_A * (1.0 - WGS84_E2) / (d * math.sqrt(d))
    return r_m, r_n


def geodetic_to_ned(home: Home, lat_deg: float, lon_deg: float, alt_m: float) -> np.ndarray:
    """Latitude, longitude [deg] and altitude AMSL [m] → NED [m] about home."""
    lat0 = math.radians(home.lat_deg)
    r_m, r_n = _radii(lat0)
    north = math.radians(lat_deg - home.lat_deg) * (r_m + home.alt_m)
    east = math.radians(lon_deg - home.lon_deg) * (r_n + home.alt_m) * math.cos(lat0)
    return np.array([north, east, home.alt_m - alt_m])


def ned_to_geodetic(home: Home, ned: np.ndarray) -> tuple[float, float, float]:
    """NED [m] about home → latitude, longitude [deg] and altitude AMSL [m]."""
    north, east, down = (float(v) for v in ned)
    lat0 = math.radians(home.lat_deg)
    r_m, r_n = _radii(lat0)
    lat = home.lat_deg + math.degrees(north / (r_m + home.alt_m))
    lon = home.lon_deg + math.degrees(east / ((r_n + home.alt_m) * math.cos(lat0)))
    return lat, lon, home.alt_m - down
