"""Per-coefficient polynomial in temperature, its degree chosen by the data, with uncertainty.

Given one coefficient's calibrated value y_i +- sigma_i at mean IMU temperatures T_i,
the model of degree d is  y(T) = c0 + c1 x + ... + cd x^d,  x = T - T_ref  (c_k in the
coefficient's unit per degC^k), fitted by weighted least squares (weights 1/sigma_i^2).

**Degree rule** (a likelihood-ratio test of nested models, the sigmas taken as known):
the candidates are d = 0 .. min(3, n - 2) for n distinct temperatures (a fit keeps at least
one degree of freedom: a cubic through 4 points fits any 4 values; one temperature gives
d = 0); the chosen degree is the
lowest d that no higher candidate d' beats significantly, i.e. for every d' > d
    chi2_d - chi2_d'  <  chi2.ppf(1 - alpha, d' - d)        (alpha = 0.01).
A term that is really there moves chi2 by (term / its sigma)^2, far above the
threshold (6.6 for one term); a term that is not moves it by a chi2(1) draw.

**Uncertainty**: the covariance of c is (A^T W A)^-1; when the chosen fit has degrees
of freedom left and chi2/dof > 1, it is scaled by chi2/dof (the Birge ratio: the
points scatter more than their sigmas say, e.g. a drift between calibrations), never
shrunk.

**Errors common to every temperature**: the same table and schedule calibrate the IMU
at every temperature, so the table's pointing errors (the black box) bias every point
alike. A common error shifts c0 only (a constant is in the model), so it cancels in the
temperature terms but not in the values. Without a split of each point's sigma into
its common and independent parts (`common_sigmas`), the fit treats every sigma as
independent (conservative for the terms and the degree test) and adds to c0's variance
the smallest point variance, the largest common part the points allow: for every
linear function of c (a value at any T, a term) the result is never narrower than the
truth for any split. With a split, the independent parts weight the fit and the largest
common variance is added to c0. At any T, `sigma(T) = sqrt(x^T C x)` is the fit's 1-sigma band (how well the
model is known there); `prediction_sigma(T)` adds in quadrature the per-temperature
calibration's own sigma interpolated at T (where one more calibration at T would fall).
Beyond the calibrated range the band widens as the polynomial does: extrapolation is
allowed: the model records the calibrated range (`range_c`) and the exports carry it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.errors import InputError

#: the highest degree considered
MAX_DEGREE = 3
#: significance level of the degree test
ALPHA = 0.01
DEGREE_RULE = (f"lowest degree d in 0..min({MAX_DEGREE}, n-2) (n distinct temperatures) that no higher degree "
               f"d' beats: "
               f"chi2_d - chi2_d' < chi2.ppf(1 - {ALPHA:g}, d' - d) (weighted least squares, sigmas known); "
               "covariance scaled by chi2/dof when that exceeds 1")


UNCERTAINTY_RULE = ("covariance (A^T W A)^-1, scaled by chi2/dof when that exceeds 1; c0's variance increased by the "
                    "common error every calibration shares (common_sigma; without a split of the sigmas, the smallest "
                    "point variance); band sigma(T) = sqrt(x^T C x), x = (1, T - reference_c, ...)")


class ThermalFitError(InputError):
    """Points a thermal polynomial cannot be fitted to (too few, no usable sigma)."""


def _design(dt: np.ndarray, degree: int) -> np.ndarray:
    return dt[:, None] ** np.arange(degree + 1)[None, :]


def _weighted_fit(dt: np.ndarray, y: np.ndarray, sigma: np.ndarray, degree: int
                  ) -> tuple[np.ndarray, np.ndarray, float]:
    """(c, covariance, chi2) of the degree-`degree` weighted fit; x scaled internally for conditioning."""
    scale = float(np.max(np.abs(dt))) or 1.0
    a = _design(dt / scale, degree) / sigma[:, None]
    b = y / sigma
    u, s, vt = np.linalg.svd(a, full_matrices=False)
    if s[-1] <= s[0] * 1e-12:
        raise ThermalFitError(f"degree {degree}: the temperatures do not separate the terms")
    coef = vt.T @ ((u.T @ b) / s)
    cov = (vt.T / s ** 2) @ vt
    chi2 = float(np.sum((a @ coef - b) ** 2))
    powers = scale ** np.arange(degree + 1)
    return coef / powers, cov / np.outer(powers, powers), chi2


@dataclass(frozen=True)
class CoefficientFit:
    """The thermal polynomial of one coefficient and the points it was fitted to."""

    name: str
    unit: str
    reference_c: float
    degree: int
    polynomial: np.ndarray         # (degree + 1,) c0..cd, unit per degC^k
    covariance: np.ndarray         # (degree + 1, degree + 1), scaled by `sigma_scale`^2
    chi2: float                    # of the chosen degree, before scaling
    dof: int
    sigma_scale: float             # sqrt(max(1, chi2/dof)) applied to the sigmas (1 when dof = 0)
    chi2_by_degree: tuple[float, ...]
    temperatures_c: np.ndarray     # the points
    values: np.ndarray
    sigmas: np.ndarray
    #: the common error added to c0 (module docstring), unit
    common_sigma: float = 0.0

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of each polynomial coefficient."""
        return np.sqrt(np.diag(self.covariance))

    def value(self, temperature_c) -> np.ndarray:
        """The model's value at `temperature_c` (a number or an array)."""
        x = _design(np.atleast_1d(np.asarray(temperature_c, float)) - self.reference_c, self.degree)
        out = x @ self.polynomial
        return out if np.ndim(temperature_c) else out[0]

    def sigma_at(self, temperature_c) -> np.ndarray:
        """The fit's 1-sigma band at `temperature_c`."""
        x = _design(np.atleast_1d(np.asarray(temperature_c, float)) - self.reference_c, self.degree)
        out = np.sqrt(np.einsum("ni,ij,nj->n", x, self.covariance, x))
        return out if np.ndim(temperature_c) else out[0]

    def prediction_sigma(self, temperature_c) -> np.ndarray:
        """The band of one more calibration at `temperature_c`: the fit's band and the points' own
        sigma (interpolated in temperature) in quadrature (the common part counted twice: an upper bound)."""
        t = np.asarray(temperature_c, float)
        order = np.argsort(self.temperatures_c)
        point = np.interp(t, self.temperatures_c[order], self.sigmas[order] * self.sigma_scale)
        return np.hypot(self.sigma_at(t), point)

    def to_json(self) -> dict[str, Any]:
        return {"unit": self.unit, "degree": self.degree, "polynomial": self.polynomial.tolist(),
                "polynomial_sigma": self.sigma.tolist(), "covariance": self.covariance.tolist(),
                "chi2": self.chi2, "dof": self.dof, "sigma_scale": self.sigma_scale,
                "chi2_by_degree": list(self.chi2_by_degree), "common_sigma": self.common_sigma,
                "points": {"temperature_c": self.temperatures_c.tolist(), "value": self.values.tolist(),
                           "sigma": self.sigmas.tolist()}}

    @classmethod
    def from_json(cls, name: str, reference_c: float, data: dict[str, Any]) -> "CoefficientFit":
        """Inverse of `to_json` (KeyError/TypeError/ValueError on a malformed entry: the caller names it)."""
        degree = int(data["degree"])
        poly = np.asarray(data["polynomial"], float).reshape(degree + 1)
        cov = np.asarray(data["covariance"], float).reshape(degree + 1, degree + 1)
        points = data["points"]
        temps, values, sigmas = (np.asarray(points[k], float).reshape(-1) for k in ("temperature_c", "value", "sigma"))
        if not (len(temps) == len(values) == len(sigmas) >= degree + 1) or not 0 <= degree <= MAX_DEGREE:
            raise ValueError("inconsistent degree and points")
        if not (np.all(np.isfinite(poly)) and np.all(np.isfinite(cov)) and np.all(np.isfinite(temps))):
            raise ValueError("non-finite numbers")
        return cls(name, str(data["unit"]), float(reference_c), degree, poly, cov, float(data["chi2"]),
                   int(data["dof"]), float(data["sigma_scale"]), tuple(float(c) for c in data["chi2_by_degree"]),
                   temps, values, sigmas, float(data.get("common_sigma", 0.0)))


def fit_coefficient(name: str, unit: str, temperatures_c, values, sigmas, reference_c: float = 25.0,
                    alpha: float = ALPHA, common_sigmas=None) -> CoefficientFit:
    """Fit one coefficient's points (module docstring: degree rule, uncertainty, common errors)."""
    t = np.asarray(temperatures_c, float).reshape(-1)
    y = np.asarray(values, float).reshape(-1)
    s = np.asarray(sigmas, float).reshape(-1)
    if not (len(t) == len(y) == len(s)) or len(t) < 1:
        raise ThermalFitError(f"{name}: needs as many temperatures, values and sigmas (at least one)")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(y))):
        raise ThermalFitError(f"{name}: temperatures and values must be finite numbers")
    if not (np.all(np.isfinite(s)) and np.all(s > 0)):
        raise ThermalFitError(f"{name}: every point needs a positive finite sigma")
    if common_sigmas is None:
        independent, common_var = s, float(np.min(s)) ** 2
    else:
        common = np.asarray(common_sigmas, float).reshape(-1)
        if common.shape != s.shape or not np.all((common >= 0) & (common <= s)):
            raise ThermalFitError(f"{name}: each common sigma must lie between 0 and the point's sigma")
        independent = np.sqrt(np.maximum(s ** 2 - common ** 2, (1e-9 * s) ** 2))
        common_var = float(np.max(common)) ** 2
    dt = t - reference_c
    distinct = len(np.unique(np.round(t, 6)))
    top = max(0, min(MAX_DEGREE, distinct - 2))     # at least one degree of freedom left
    fits = [_weighted_fit(dt, y, independent, d) for d in range(top + 1)]
    chi2s = [f[2] for f in fits]
    # local: scipy.stats takes half a second to import; every run's finish imports this module, few fit
    from scipy.stats import chi2 as chi2_distribution

    degree = next(d for d in range(top + 1)
                  if all(chi2s[d] - chi2s[e] < chi2_distribution.ppf(1.0 - alpha, e - d)
                         for e in range(d + 1, top + 1)))
    poly, cov, chi2 = fits[degree]
    dof = len(t) - (degree + 1)
    scale = math.sqrt(max(1.0, chi2 / dof)) if dof > 0 else 1.0
    cov = cov * scale ** 2
    cov[0, 0] += common_var
    return CoefficientFit(name, unit, float(reference_c), degree, poly, cov, chi2, dof, scale,
                          tuple(chi2s), t, y, s, float(math.sqrt(common_var)))


__all__ = ["ALPHA", "DEGREE_RULE", "MAX_DEGREE", "UNCERTAINTY_RULE", "CoefficientFit", "ThermalFitError",
           "fit_coefficient"]
