"""The Earth's orientation and shape: inertial positions to geodetic latitude, longitude and
altitude, as an upper-atmosphere model takes them.  Pure functions, no I/O.

Frame approximation: the truth's inertial frame N is taken as the true equator and equinox of
date (its z axis is the spin axis J2 acts about), and the Earth-fixed frame is N turned about z
by the Greenwich mean sidereal time (IAU 1982 expression) with UT1 = UTC.  Precession since the
epoch, nutation (up to about 20 arcsec in longitude), polar motion and UT1 - UTC (under 1 s,
0.004 deg of longitude) are neglected: together well under 0.01 deg of longitude and latitude
over a mission of days, far below the scales on which thermospheric density varies.  Latitude
and altitude are geodetic on the WGS84 ellipsoid.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "WGS84_A",
    "WGS84_F",
    "geodetic",
    "gmst",
    "inertial_to_geodetic",
]

WGS84_A: float = 6378137.0
"""WGS84 semi-major axis, m."""

WGS84_F: float = 1.0 / 298.257223563
"""WGS84 flattening."""

_E2 = WGS84_F * (2.0 - WGS84_F)  # first eccentricity squared


def gmst(days_since_j2000: ArrayLike) -> FloatArray:
    """Greenwich mean sidereal time, rad in [0, 2 pi), (M,) -> (M,) (or () -> ()), from UT1
    days since J2000.0 (IAU 1982 expression)."""
    d = np.asarray(days_since_j2000, dtype=float)
    if not np.all(np.isfinite(d)):
        raise ValueError("days_since_j2000 must be finite")
    t = d / 36525.0
    deg = 280.46061837 + 360.98564736629 * d + (0.000387933 - t / 38710000.0) * t * t
    return np.mod(np.radians(np.mod(deg, 360.0)), 2.0 * math.pi)


def geodetic(r_E: ArrayLike) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Geodetic latitude (rad), longitude (rad, in (-pi, pi]) and altitude (m) on WGS84 of
    Earth-fixed positions r_E (M, 3) m -> three (M,) arrays.

    Fixed-point iteration on the latitude, five passes: below 2000 km altitude it converges
    to under 1e-12 rad; the altitude form p cos(lat) + z sin(lat) - a sqrt(1 - e^2 sin^2 lat)
    holds at the poles too."""
    r = np.asarray(r_E, dtype=float)
    if r.ndim != 2 or r.shape[1] != 3 or not np.all(np.isfinite(r)):
        raise ValueError(f"r_E must be finite with shape (M, 3), got shape {r.shape}")
    x, y, z = r[:, 0], r[:, 1], r[:, 2]
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - _E2))
    for _ in range(5):
        s = np.sin(lat)
        n = WGS84_A / np.sqrt(1.0 - _E2 * s * s)
        lat = np.arctan2(z + _E2 * n * s, p)
    s, c = np.sin(lat), np.cos(lat)
    alt = p * c + z * s - WGS84_A * np.sqrt(1.0 - _E2 * s * s)
    return lat, np.arctan2(y, x), alt


def inertial_to_geodetic(
    r_N: ArrayLike, days_since_j2000: ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Geodetic latitude (deg), longitude (deg, in (-180, 180]) and altitude (m) of inertial
    positions r_N (M, 3) m at UT1 days since J2000.0 (M,) (see the module's frame
    approximation)."""
    r = np.asarray(r_N, dtype=float)
    theta = gmst(days_since_j2000)
    if r.ndim != 2 or r.shape[1] != 3 or theta.shape != (r.shape[0],):
        raise ValueError(
            f"r_N must have shape (M, 3) and days_since_j2000 (M,), got {r.shape} and {theta.shape}"
        )
    c, s = np.cos(theta), np.sin(theta)
    r_E = np.column_stack((c * r[:, 0] + s * r[:, 1], c * r[:, 1] - s * r[:, 0], r[:, 2]))
    lat, lon, alt = geodetic(r_E)
    return np.degrees(lat), np.degrees(lon), alt
