"""Noise terms read off an Allan deviation curve (IEEE Std 952-1997 Annex C) by fitting the whole curve.

The Allan variance is the sum of the variances of independent processes, each a known
function of tau (`bench.noise.covariance`):

    AVAR = 3 Q^2 / tau^2 + N^2 / tau + A + K^2 tau / 3 + s^2 GM(tau / T)

quantisation Q (white PM), random walk N (ARW for a gyro, VRW for an accelerometer:
the -1/2 line's value at tau = 1 s), flicker A (flat), rate random walk K (+1/2) and a
first-order Gauss-Markov bias (sigma s, correlation time T: a bump peaking at 1.89 T;
the simulated IMU's bias is one, and a real sensor's correlated bias often looks like
one). `model_fit` fits the coefficients, non-negative, by generalised least squares with
the full covariance of the points: overlapping estimates at neighbouring taus correlate
by 0.5-0.8, so weighting them as independent (or by their own noisy values) gives
uncertainties several times too small and a low bias. T is tried at every tau two
octaves inside the fitted ones (a bump is only told apart from white noise and from a
random walk when the curve shows both its sides) and the fits are averaged with weights
exp(-chi2 / 2), their spread added to the covariance. The fit starts at the longest run
of -1/2 slopes with m >= MIN_WHITE_M and moves on while the chi-square says the model
does not describe the points (the shortest clusters carry the sampling: a quantiser's
pattern, filters).

The terms, each with the 1 sigma of the fit's covariance (scaled by chi2/dof when the
points scatter more than the model says):

- N = sqrt(c_white) (a 2-sigma upper bound, flagged, when c_white is below 2 sigma: white
  noise hidden under quantisation and a bias over all the fitted taus); Q = sqrt(c_pm / 3)
  when above 2 sigma (else read from the leading -1 slope, as before);
- bias instability B = the minimum of the fitted curve over the measured taus / 0.664
  (IEEE's flat-region reading; 0.664 = sqrt(2 ln 2 / pi)); the fitted curve averages
  the neighbouring points, so B is not biased low as the lowest noisy point is. When the
  fitted curve still falls at the longest tau, B is flagged `upper_bound` (the floor may
  lie beyond the record);
- rate random walk K = sqrt(3 c_rrw); when c_rrw is below 2 sigma the record cannot tell
  it from zero and K is given as a 2-sigma upper bound (`upper_bound`; its sigma is
  sqrt(3 sigma_c)).

A curve too short for the model (fewer than 3 usable points) has its terms read off the
slopes (`_region_fit`: -1/2 points, the minimum, the +1/2 points).

No term is read off a single Allan point: one point cannot tell its term from the
others (at the shortest tau it also carries the sampling's own pattern). Such a term is
left out and `ChannelFit.not_resolved` says why. A record shorter than
`MIN_RECORD_SAMPLES` is refused before any fit (`bench.noise.result.check_record_length`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np
from scipy.special import gammaincc

from bench.noise.allan import AllanCurve, local_slopes
from bench.noise.covariance import avar_covariance, basis, cross_terms

#: ADEV of flicker FM (bias instability B) is B * sqrt(2 ln 2 / pi) = 0.664 B (IEEE 952 Table C.2).
FLICKER_FACTOR = math.sqrt(2.0 * math.log(2.0) / math.pi)
#: Peak ADEV of a first-order Gauss-Markov process per unit sigma, and where it peaks (tau / T).
GM_PEAK_ADEV, GM_PEAK_TAU = 0.6173642831, 1.8926176809
_WHITE_SLOPES = (-0.6, -0.4)
_QUANT_SLOPE = -0.75
MIN_WHITE_M = 8
#: The model fit starts at the first point from which its chi-square probability exceeds this.
CONSISTENT = 1e-3
_FLAT = 0.25
_RISE = 0.25
#: The model has five coefficients (quantisation, white, flicker, random walk, Gauss-Markov): fitting them with a
#: degree of freedom to spare takes six octave points from the white-noise start (m = MIN_WHITE_M ... 32
#: MIN_WHITE_M), each with MIN_CLUSTERS (4) clusters: 4 x 8 x 32 = 1024 samples.
MODEL_COEFFICIENTS = 5
MIN_RECORD_SAMPLES = 4 * MIN_WHITE_M * 2 ** MODEL_COEFFICIENTS


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
    model: dict | None = None      # the model fit (`ModelFit.summary`), None when the terms were read off slopes
    #: term attribute -> why it is not given (a term the record cannot resolve is not reported as a number)
    not_resolved: dict[str, str] = field(default_factory=dict)

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


def _single_point(curve: AllanCurve, idx: list[int], what: str) -> str:
    """Why a term seen at one Allan point only is not given."""
    return (f"{what} at one Allan point only (tau {float(curve.tau_s[idx[0]]):g} s): one point cannot tell it from "
            "the other terms")


def _term(curve: AllanCurve, idx: list[int], slope: float, scale: float) -> TermFit:
    """The term of an ADEV line of `slope` fitted over `idx` (at least two points: see `_single_point`)."""
    if len(idx) < 2:
        raise ValueError("a term is never read off a single Allan point")
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


def _model_points(curve: AllanCurve) -> list[int]:
    """The points the noise model may be fitted on: from the longest run of slope -1/2 with m >= MIN_WHITE_M on
    (the curve's points from m >= MIN_WHITE_M if it has none; all of them for a very short curve)."""
    central = local_slopes(curve.tau_s, curve.adev)
    usable = [i for i in range(len(curve.m)) if curve.m[i] >= MIN_WHITE_M]
    white = _contiguous([i for i in usable if _WHITE_SLOPES[0] <= central[i] <= _WHITE_SLOPES[1]])
    idx = [i for i in usable if i >= white[0]] if white else usable
    return idx if len(idx) >= 4 else list(range(len(curve.m)))


@lru_cache(maxsize=256)
def _cross_cached(m: tuple[int, ...], n_phase: int, tau0: float, correlation_time_s: float | None) -> np.ndarray:
    return cross_terms(np.array(m), n_phase, tau0, correlation_time_s)


@dataclass(frozen=True)
class ModelFit:
    """The curve's AVAR fitted as sum c_p basis_p(tau) (`bench.noise.covariance.TERMS`) by generalised least squares.

    One fit per Gauss-Markov correlation time tried (`candidates`: (weight, coefficients, covariance, T)); the
    estimates are their average weighted by exp(-chi2 / 2), and their covariance adds the spread between the
    candidates to each one's own, so that the correlation time's own uncertainty is carried."""

    candidates: tuple[tuple[float, np.ndarray, np.ndarray, float | None], ...]
    points: tuple[int, ...]
    chi2: float
    dof: int

    @property
    def coefficients(self) -> np.ndarray:
        return np.sum([w * c for w, c, _, _ in self.candidates], axis=0)

    @property
    def covariance(self) -> np.ndarray:
        mean = self.coefficients
        return np.sum([w * (cov + np.outer(c - mean, c - mean)) for w, c, cov, _ in self.candidates], axis=0)

    def parts(self, tau_s: np.ndarray) -> np.ndarray:
        """(len(tau), 5) each term's AVAR at `tau_s` (weighted over the candidates)."""
        return np.sum([w * basis(tau_s, t) * c for w, c, _, t in self.candidates], axis=0)

    def avar(self, tau_s: np.ndarray) -> np.ndarray:
        return self.parts(tau_s).sum(axis=1)

    def avar_sigma(self, tau_s: np.ndarray) -> np.ndarray:
        mean = self.avar(tau_s)
        var = np.zeros(len(mean))
        for w, c, cov, t in self.candidates:
            x = basis(tau_s, t)
            var += w * (np.einsum("ip,pq,iq->i", x, cov, x) + (x @ c - mean) ** 2)
        return np.sqrt(np.maximum(var, 0.0))


    def summary(self, curve: AllanCurve) -> dict:
        """JSON: the fitted taus, chi-square, the Gauss-Markov correlation times tried with their weights, the
        fitted ADEV at every tau of the curve and its 1 sigma."""
        tau = curve.tau_s
        return {"fit_tau_s": [float(tau[self.points[0]]), float(tau[self.points[-1]])],
                "points": [int(i) for i in self.points],
                "chi2": self.chi2, "dof": self.dof,
                "gauss_markov": [{"weight": w, "correlation_time_s": t, "sigma": math.sqrt(c[4])}
                                 for w, c, _, t in self.candidates if t is not None and w >= 0.01],
                "adev": np.sqrt(self.avar(tau)).tolist(),
                "adev_sigma": (0.5 * self.avar_sigma(tau) / np.sqrt(self.avar(tau))).tolist()}


def _gls(x: np.ndarray, avar: np.ndarray, cross: np.ndarray, start: np.ndarray, columns: list[int],
         iterations: int = 6) -> tuple[np.ndarray, np.ndarray, float]:
    """Non-negative generalised least squares of `avar` on `x`'s `columns`, the covariance re-made from each fit:
    (coefficients, whitened design of `columns`, chi2)."""
    # local: scipy.optimize takes a third of a second to import; a calibration run's finish imports this module
    # and never fits a noise model
    from scipy.optimize import nnls

    coef = start.copy()
    chi2, design = math.inf, x[:, columns]
    for _ in range(iterations):
        cov = avar_covariance(cross, coef)
        cov += np.diag(np.full(len(avar), 1e-12) * avar ** 2)      # never singular
        try:
            whiten = np.linalg.inv(np.linalg.cholesky(cov))
        except np.linalg.LinAlgError:
            break
        a, b = whiten @ x[:, columns], whiten @ avar
        found, _ = nnls(a, b, maxiter=50 * len(columns))
        new = np.zeros(len(coef))
        new[columns] = found
        if not np.any(new > 0):
            break
        done = np.allclose(new, coef, rtol=1e-4, atol=0.0)
        coef, design, chi2 = new, a, float(np.sum((b - a @ found) ** 2))
        if done:
            break
    return coef, design, chi2


def _fit_points(curve: AllanCurve, idx: list[int], all_idx: list[int]) -> ModelFit | None:
    # local: see _gls
    from scipy.optimize import nnls

    tau, avar = curve.tau_s[idx], curve.adev[idx] ** 2
    m = tuple(int(v) for v in curve.m[all_idx])
    sub = [all_idx.index(i) for i in idx]
    n_phase, tau0 = curve.n_samples + 1, 1.0 / curve.rate_hz
    w = np.sqrt(curve.edf[idx] / 2.0) / avar         # a start from independent points (var = 2 AVAR^2 / edf)
    start = np.zeros(5)
    start[:4], _ = nnls(basis(tau, None)[:, :4] * w[:, None], avar * w)
    if not np.any(start > 0):
        return None
    fits = []
    # A Gauss-Markov bias is told apart from white noise (far above its peak at 1.89 T it falls as -1/2) and from
    # a random-walk bias (far below it rises as +1/2) only when the curve shows both sides of its peak: two
    # octaves of fitted taus on either side.
    peaks = [float(t) for t in tau if 4.0 * tau[0] * (1 - 1e-9) <= t <= tau[-1] / 4.0 * (1 + 1e-9)]
    for correlation_time_s in [None] + [t / GM_PEAK_TAU for t in peaks]:
        columns = [0, 1, 2, 3] + ([4] if correlation_time_s is not None else [])
        cross = _cross_cached(m, n_phase, tau0, correlation_time_s)[np.ix_(sub, sub)]
        coef, design, chi2 = _gls(basis(tau, correlation_time_s), avar, cross, start, columns)
        if math.isfinite(chi2):
            # every coefficient of the model free (also those NNLS holds at 0: the record does not rule them out,
            # and holding them there claimed RRW and bias-instability sigmas far too small in trials)
            cov = np.zeros((5, 5))
            cov[np.ix_(columns, columns)] = np.linalg.pinv(design.T @ design)
            fits.append((chi2, coef, cov, correlation_time_s, int(np.sum(coef[columns] > 0))))
    if not fits:
        return None
    chi2_min, *_, n_active = min(fits, key=lambda f: f[0])
    dof = max(len(idx) - n_active, 1)
    birge = max(1.0, chi2_min / dof)                     # points scattering more than the model says
    weights = np.array([math.exp(-(f[0] - chi2_min) / (2.0 * birge)) for f in fits])
    weights /= weights.sum()
    candidates = tuple((float(wk), f[1], f[2] * birge, f[3]) for wk, f in zip(weights, fits) if wk > 1e-6)
    total = sum(c[0] for c in candidates)
    candidates = tuple((wk / total, c, cov, t) for wk, c, cov, t in candidates)
    return ModelFit(candidates, tuple(idx), chi2_min, dof)


def model_fit(curve: AllanCurve) -> ModelFit | None:
    """Fit quantisation, white, flicker, random-walk and (correlation times tried over the taus) Gauss-Markov terms
    to the curve, the points weighted with their full covariance (`bench.noise.covariance`).

    The shortest clusters carry the sampling itself (the integrator's smoothing, a quantiser's pattern when the
    increments are near whole counts, an anti-alias filter) that no noise term describes: the fit starts at the
    first point from which the model is consistent with the points (chi-square probability above 0.001)."""
    all_idx = _model_points(curve)
    if len(all_idx) < 3:
        return None
    fit = None
    for first in range(len(all_idx) - 3):
        fit = _fit_points(curve, all_idx[first:], all_idx)
        if fit is not None and gammaincc(fit.dof / 2.0, fit.chi2 / 2.0) > CONSISTENT:
            break
    return fit


def _dominant(model: ModelFit, tau: np.ndarray, column: int, idx: tuple[int, ...]) -> list[int]:
    """The points of `idx` where term `column` is the model's largest."""
    parts = model.parts(tau)
    return [i for i in idx if np.argmax(parts[i]) == column]


def _region(curve: AllanCurve, points: list[int]) -> tuple[float, float]:
    return float(curve.tau_s[points[0]]), float(curve.tau_s[points[-1]])


def fit_curve(curve: AllanCurve) -> ChannelFit:
    """Quantisation, random walk, bias instability and rate random walk of one Allan curve.

    The curve's AVAR is fitted as the sum of the IEEE 952 terms plus a Gauss-Markov bias (`model_fit`), with the
    points' full covariance; each term's 1 sigma comes from the fit's covariance. The bias instability is the
    minimum of the fitted curve over the measured taus / 0.664 (the IEEE reading, without the low bias of the
    lowest noisy point); a rate random walk the record cannot tell from zero (below 2 sigma) is given as a 2-sigma
    upper bound (`upper_bound`)."""
    tau, adev = curve.tau_s, curve.adev
    n = len(tau)
    if n == 0 or not np.all(adev > 0):
        return ChannelFit(None, None, None, None)
    model = model_fit(curve)
    if model is None:
        return _region_fit(curve)
    c, cov = model.coefficients, model.covariance
    sig = np.sqrt(np.maximum(np.diag(cov), 0.0))
    idx = list(model.points)

    random_walk = _resolved_or_bound(curve, model, 1, 1.0, idx[0])

    fitted = model.avar(tau[idx])
    k = int(np.argmin(fitted))
    floor = fitted[k]
    b = math.sqrt(floor) / FLICKER_FACTOR
    b_sigma = 0.5 * b * float(model.avar_sigma(tau[[idx[k]]])[0]) / floor
    lo = hi = k
    while lo > 0 and fitted[lo - 1] <= 1.5 * floor:
        lo -= 1
    while hi < len(idx) - 1 and fitted[hi + 1] <= 1.5 * floor:
        hi += 1
    flat = idx[lo:hi + 1]
    still_falling = k == len(idx) - 1 and len(idx) > 1 and fitted[-1] < fitted[-2]
    bias = TermFit(b, b_sigma, tuple(flat), _region(curve, flat), upper_bound=still_falling)

    rate_random_walk = _resolved_or_bound(curve, model, 3, 3.0, idx[-1])

    quantisation = None
    not_resolved: dict[str, str] = {}
    if c[0] > 2.0 * sig[0]:
        value = math.sqrt(c[0] / 3.0)
        points = _dominant(model, tau, 0, model.points) or [idx[0]]
        quantisation = TermFit(value, value * 0.5 * sig[0] / c[0], tuple(points), _region(curve, points))
    else:
        quant_idx = _leading_quantisation(curve)
        if len(quant_idx) > 1:
            quantisation = _term(curve, quant_idx, -1.0, 1.0 / math.sqrt(3.0))
        elif quant_idx:
            not_resolved["quantisation"] = _single_point(curve, quant_idx, "a slope steeper than -3/4")
    return ChannelFit(quantisation, random_walk, bias, rate_random_walk, model.summary(curve), not_resolved)


def _resolved_or_bound(curve: AllanCurve, model: ModelFit, column: int, scale: float, fallback: int) -> TermFit | None:
    """sqrt(scale c) of coefficient `column` with its 1 sigma, or, when c is below 2 sigma (the record cannot tell
    it from zero), a 2-sigma upper bound sqrt(scale (c + 2 sigma)) with sigma sqrt(scale sigma_c)."""
    c = float(model.coefficients[column])
    sig = math.sqrt(max(float(model.covariance[column, column]), 0.0))
    if c <= 0 and sig <= 0:
        return None
    points = _dominant(model, curve.tau_s, column, model.points) or [fallback]
    if c > 2.0 * sig:
        value = math.sqrt(scale * c)
        return TermFit(value, value * 0.5 * sig / c, tuple(points), _region(curve, points))
    return TermFit(math.sqrt(scale * (c + 2.0 * sig)), math.sqrt(scale * sig), tuple(points), _region(curve, points),
                   upper_bound=True)


def _leading_quantisation(curve: AllanCurve) -> list[int]:
    """The leading run of points steeper than -3/4."""
    central = local_slopes(curve.tau_s, curve.adev)
    out = []
    for i in range(len(central)):
        if central[i] < _QUANT_SLOPE:
            out.append(i)
        else:
            break
    return out


def _region_fit(curve: AllanCurve) -> ChannelFit:
    """Terms read from the slopes alone (a curve too short for the model fit: fewer than 3 points)."""
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
    not_resolved: dict[str, str] = {}
    bias: TermFit | None = None
    if still_falling:
        not_resolved["bias_instability"] = (f"the curve still falls at the record's longest tau "
                                            f"({float(tau[-1]):g} s): the record is too short to reach its floor")
    else:
        b = adev[i_min] / FLICKER_FACTOR
        b_sigma = b / math.sqrt(2.0 * float(curve.edf[i_min]))
        flat = list(range(lo, hi + 1))
        bias = TermFit(float(b), float(b_sigma), tuple(flat), (float(tau[flat[0]]), float(tau[flat[-1]])))

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
    # the -1/2 points and those after them up to the flat region
    white_region = list(range(white_idx[0], max(lo, white_idx[-1] + 1))) if white_idx else []
    if len(white_region) > 1:
        quantisation, random_walk = _short_tau_fit(curve, white_region)
    elif white_region:
        not_resolved["random_walk"] = _single_point(curve, white_region, "a -1/2 slope")
    if quantisation is None and len(quant_idx) > 1:
        quantisation = _term(curve, quant_idx, -1.0, 1.0 / math.sqrt(3.0))
    elif quantisation is None and quant_idx:
        not_resolved["quantisation"] = _single_point(curve, quant_idx, "a slope steeper than -3/4")
    rate_random_walk = None
    if len(rrw_idx) > 1:
        rate_random_walk = _term(curve, rrw_idx, 0.5, math.sqrt(3.0))
    elif rrw_idx:
        not_resolved["rate_random_walk"] = _single_point(curve, rrw_idx, "a +1/2 rise")
    return ChannelFit(quantisation, random_walk, bias, rate_random_walk, None, not_resolved)


__all__ = ["FLICKER_FACTOR", "MIN_RECORD_SAMPLES", "ChannelFit", "TermFit", "fit_curve"]
