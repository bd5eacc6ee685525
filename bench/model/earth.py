"""Earth model at the test site: normal gravity and Earth rate in ENU."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.errors import InputError
from bench.model.units import DEG

EARTH_RATE = 7.2921151467e-5  # rad/s (WGS84)
# WGS84 constants for Somigliana's normal gravity and its free-air height correction.
_GE = 9.7803253359
_K = 0.00193185265241
_E2 = 0.00669437999013
_A = 6378137.0
_F = 1.0 / 298.257223563
_M = 0.00344978650684

HANGZHOU_LATITUDE_DEG = 30.27  # the paper's site


def normal_gravity(latitude_deg: float, height_m: float = 0.0) -> float:
    """WGS84 normal gravity (m/s^2) at latitude and ellipsoidal height."""
    s2 = math.sin(latitude_deg * DEG) ** 2
    g0 = _GE * (1.0 + _K * s2) / math.sqrt(1.0 - _E2 * s2)
    h = height_m
    return g0 * (1.0 - 2.0 / _A * (1.0 + _F + _M - 2.0 * _F * s2) * h + 3.0 * h * h / (_A * _A))


@dataclass(frozen=True)
class Site:
    """Where the turntable stands. `local_g` (m/s^2) overrides the normal gravity formula."""

    latitude_deg: float = HANGZHOU_LATITUDE_DEG
    height_m: float = 0.0
    local_g: float | None = None

    def __post_init__(self) -> None:
        if not -90.0 <= self.latitude_deg <= 90.0:
            raise InputError(f"latitude_deg must be within [-90, 90], got {self.latitude_deg}")
        if self.local_g is not None and not 9.7 <= self.local_g <= 9.9:
            raise InputError(f"local_g must be a plausible gravity (9.7 to 9.9 m/s^2), got {self.local_g}")

    @property
    def gravity(self) -> float:
        """Magnitude of the specific force at rest, m/s^2."""
        return self.local_g if self.local_g is not None else normal_gravity(self.latitude_deg, self.height_m)

    @property
    def specific_force_enu(self) -> np.ndarray:
        """Specific force of a body at rest in ENU: `[0, 0, g]`."""
        return np.array([0.0, 0.0, self.gravity])

    @property
    def earth_rate_enu(self) -> np.ndarray:
        """Earth rate in ENU: `Omega * [0, cos L, sin L]` (rad/s)."""
        lat = self.latitude_deg * DEG
        return EARTH_RATE * np.array([0.0, math.cos(lat), math.sin(lat)])

    def to_dict(self) -> dict:
        return {"latitude_deg": self.latitude_deg, "height_m": self.height_m, "local_g": self.local_g}
