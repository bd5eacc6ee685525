"""Noise terms read off an Allan deviation curve (IEEE Std 952-1997 Annex C), fit regions chosen automatically.

Each term is a straight line of known slope in log-log (ADEV in the channel's unit,
tau in s); the points where the curve has that slope form its region:

- quantisation, slope -1: ADEV = sqrt(3) Q / tau, and random walk (ARW for a gyro, VRW
  for an accelerometer), slope -1/2: ADEV = N / sqrt(tau), N the line's value at tau =
  1 s: fitted together as AVAR = 3 Q^2 / tau^2 + N^2 / tau on the points up to the end
  of the -1/2 region (local slope in [-0.6, -0.4]); Q's region is where its line is the
  larger;
- bias instability, slope 0: B = min ADEV / 0.664 (sqrt(2 ln 2 / pi)), at the minimum; the
  flat region is the run of points around it whose neighbour slopes stay within +-1/4.
  When the curve still falls at its last point the minimum is not reached and B is an
  upper bound (`upper_bound`);
- rate random walk, slope +1/2: ADEV = K sqrt(tau / 3) (the points after the flat region
  rising faster than +1/4).

Uncertainty (1 sigma) of a term, relative: the larger of the chi-square spread of the
region's best-determined point, 1 / sqrt(2 edf) (neighbouring overlapping points are
strongly correlated, so averaging them does not reduce it), and the scatter of the
region's points about the line.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.noise.allan import AllanCurve, local_slopes

#: ADEV of flicker FM (bias instability B) is B * sqrt(2 ln 2 / pi) = 0.664 B (IEEE 952 Table C.2).
FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
_WHITE_SLOPES = (-0.6, -0.4)
_QUANT_SLOPE = -0.75
MIN_WHITE_M = 8
_FLAT = 0.25
_RISE = 0.25


@dataclass(frozen=True)
class TermFit:
    """One noise term in the channel's Allan units (see `FitUnits`): value, 1 sigma, the points it was read from."""

    value: float
    sigma: float
    points: tuple[int, ...]         # indices into the curve's taus
    tau_s: tuple[float, float]      # first and last tau of the region
    upper_bound: bool = False       # bias instability whose minimum the record does not reach


@dataclass(frozen=True)
class ChannelFit:
    """The terms found on one curve, in the curve's unit (coefficient of each line; see module doc)."""

    quantisation: TermFit | None   # Q: ADEV = sqrt(3) Q / tau  (unit x s)
    random_walk: TermFit | None    # N: ADEV = N / sqrt(tau)    (unit x sqrt(s))
    bias_instability: TermFit | None  # B: min ADEV / 0.664      (unit)
    rate_random_walk: TermFit | None  # K: ADEV = K sqrt(tau/3) (unit / sqrt(s))

    def line(self, term: str, tau_s: np.ndarray) -> np.ndarray | None:
        """The fitted line of `term` at `tau_s` (None if the term was not found)."""
        fit = getattr(self, term)
        if fit is None:
            return None
        tau = np.asarray(tau_s, dtype=float)
        if term == "quantisation":
            return math.sqrt(3.0) * fit.value / tau
        if term == "random_walk":
            return fit.value / np.sqrt(tau)
        if term == "bias_instability":
            return np.full(tau.shape, fit.value * FLICKER_FACTOR)
        return fit.value * np.sqrt(tau / 3.0)


def _line_fit(curve: AllanCurve, idx: list[int], slope: float) -> tuple[float, float]:
    """ln(coefficient) of ADEV = c * tau^slope over `idx` (weights 2 edf) and its 1-sigma."""
    ln_c = np.log(curve.adev[idx]) - slope * np.log(curve.tau_s[idx])
    w = 2.0 * curve.edf[idx]
    mean = float(np.sum(w * ln_c) / np.sum(w))
    statistical = 1.0 / math.sqrt(float(np.max(w)))
    scatter = float(np.sqrt(np.sum(w * (ln_c - mean) ** 2) / np.sum(w))) if len(idx) > 1 else 0.0
    return mean, max(statistical, scatter)


def _term(curve: AllanCurve, idx: list[int], slope: float, scale: float) -> TermFit:
    ln_c, sigma_ln = _line_fit(curve, idx, slope)
    value = scale * math.exp(ln_c)
    return TermFit(value, value * sigma_ln, tuple(idx), (float(curve.tau_s[idx[0]]), float(curve.tau_s[idx[-1]])))


def _short_tau_fit(curve: AllanCurve, idx: list[int]) -> tuple[TermFit | None, TermFit | None]:
    """Quantisation Q and random walk N fitted on AVAR = 3 Q^2 / tau^2 + N^2 / tau + c tau over `idx`.

    Non-negative weighted least squares with var(AVAR_i) = 2 AVAR_i^2 / edf_i. The
    neighbours are in the fit because a little quantisation at the shortest taus (the
    best-determined points) or the rise of a correlated bias (a Gauss-Markov bias rises
    as +1/2 well below its correlation time) at the long end would otherwise pull N up.
    Relative 1-sigma of N: the largest of the covariance's, the region's best point's
    1 / sqrt(2 edf) (neighbouring points are correlated) and the points' scatter about
    the fitted curve."""
    tau, avar, edf = curve.tau_s[idx], curve.adev[idx] ** 2, curve.edf[idx]
    w = np.sqrt(edf / 2.0) / avar                   # 1 / sigma of each AVAR
    design = np.column_stack([3.0 / tau ** 2, 1.0 / tau, tau])
    active = [1] if len(idx) < 3 else ([0, 1, 2] if len(idx) >= 4 else [0, 1])
    while True:
        coef_active, cov_active = _wls(design[:, active], avar, w)
        negative = [col for col, c in zip(active, coef_active) if c <= 0 and col != 1]
        if not negative:
            break
        active = [col for col in active if col not in negative]
    coef, cov = np.zeros(3), np.zeros((3, 3))
    coef[active] = coef_active
    cov[np.ix_(active, active)] = cov_active
    if coef[1] <= 0:
        return None, None
    ln_residual = 0.5 * np.log(avar / (design @ coef))     # of ADEV
    scatter = math.sqrt(float(np.sum(edf * ln_residual ** 2) / np.sum(edf)))
    best = max(1.0 / math.sqrt(2.0 * float(np.max(edf))), scatter)
    n_value = math.sqrt(coef[1])
    n_rel = max(0.5 * math.sqrt(cov[1, 1]) / coef[1], best)
    region = (float(tau[0]), float(tau[-1]))
    random_walk = TermFit(n_value, n_value * n_rel, tuple(idx), region)
    quantisation = None
    if coef[0] > 0:
        q_value = math.sqrt(coef[0])
        q_rel = max(0.5 * math.sqrt(cov[0, 0]) / coef[0], best)
        q_points = tuple(i for i, t in zip(idx, tau) if 3.0 * coef[0] / t ** 2 > coef[1] / t) or (idx[0],)
        quantisation = TermFit(q_value, q_value * q_rel, q_points,
                               (float(curve.tau_s[q_points[0]]), float(curve.tau_s[q_points[-1]])))
    return quantisation, random_walk


def _wls(design: np.ndarray, y: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted least squares (w = 1 / sigma): coefficients and their covariance."""
    a = design * w[:, None]
    coef, *_ = np.linalg.lstsq(a, y * w, rcond=None)
    cov = np.linalg.pinv(a.T @ a)
    return coef, cov


def _contiguous(idx: list[int], anchor: int | None = None) -> list[int]:
    """The longest run of consecutive indices (the one holding `anchor`, if given)."""
    runs: list[list[int]] = []
    for i in idx:
        if runs and i == runs[-1][-1] + 1:
            runs[-1].append(i)
        else:
            runs.append([i])
    if not runs:
        return []
    if anchor is not None:
        for run in runs:
            if anchor in run:
                return run
    return max(runs, key=len)


def fit_curve(curve: AllanCurve) -> ChannelFit:
    """Quantisation, random walk, bias instability and rate random walk of one Allan curve."""
    tau, adev = curve.tau_s, curve.adev
    n = len(tau)
    if n == 0 or not np.all(adev > 0):
        return ChannelFit(None, None, None, None)
    central = local_slopes(tau, adev)
    adjacent = np.diff(np.log(adev)) / np.diff(np.log(tau)) if n > 1 else np.zeros(0)

    # Flat region around the minimum.
    i_min = int(np.argmin(adev))
    lo = i_min
    while lo > 0 and adjacent[lo - 1] > -_FLAT:
        lo -= 1
    hi = i_min
    while hi < n - 1 and adjacent[hi] < _FLAT:
        hi += 1
    still_falling = i_min == n - 1 and n > 1 and adjacent[-1] <= -_FLAT
    b = adev[i_min] / FLICKER_FACTOR
    b_sigma = b / math.sqrt(2.0 * float(curve.edf[i_min]))
    flat = list(range(lo, hi + 1)) if not still_falling else [i_min]
    bias = TermFit(float(b), float(b_sigma), tuple(flat), (float(tau[flat[0]]), float(tau[flat[-1]])),
                   upper_bound=still_falling)

    before = range(0, lo if not still_falling else n)
    quant_idx = []
    for i in before:                       # the leading run steeper than -3/4
        if central[i] < _QUANT_SLOPE:
            quant_idx.append(i)
        else:
            break
    # The first few cluster sizes carry the sampling itself (the integrator's smoothing, a quantiser's
    # pattern when the increments are near whole counts): the -1/2 line is read from m >= MIN_WHITE_M.
    white_idx = _contiguous([i for i in before if _WHITE_SLOPES[0] <= central[i] <= _WHITE_SLOPES[1]
                             and i not in quant_idx and curve.m[i] >= MIN_WHITE_M])
    rrw_idx = _contiguous([i for i in range(hi + 1, n) if central[i] > _RISE and adjacent[i - 1] > 0])
    if still_falling:
        rrw_idx = []

    quantisation = random_walk = None
    if white_idx:
        # the -1/2 points and those after them up to the flat region
        quantisation, random_walk = _short_tau_fit(curve, list(range(white_idx[0], max(lo, white_idx[-1] + 1))))
        if quantisation is None and quant_idx:
            quantisation = _term(curve, quant_idx, -1.0, 1.0 / math.sqrt(3.0))
    elif quant_idx:
        quantisation = _term(curve, quant_idx, -1.0, 1.0 / math.sqrt(3.0))
    rate_random_walk = _term(curve, rrw_idx, 0.5, math.sqrt(3.0)) if rrw_idx else None
    return ChannelFit(quantisation, random_walk, bias, rate_random_walk)


__all__ = ["FLICKER_FACTOR", "ChannelFit", "TermFit", "fit_curve"]
