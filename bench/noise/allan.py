"""Overlapping Allan deviation with confidence intervals (IEEE Std 952-1997 Annex C; NIST SP 1065).

The input is a rate series `y` (one channel: deg/h for a gyro, ug for an
accelerometer) sampled at `rate_hz`. As `allantools.oadev(..., data_type="freq")`
does, the mean is removed, the series integrated to a "phase" `x` (zero prepended)
and, for each cluster size `m` (tau = m / rate_hz),

    AVAR(tau) = sum_k (x[k+2m] - 2 x[k+m] + x[k])^2 / (2 tau^2 (N - 2m)),  N = len(x).

Each tau is one pass over `x` in cache-sized blocks (no full-length temporaries), and
the channels are spread over threads (numpy releases the GIL), so 6 channels of
28.8 M samples take seconds.

Confidence intervals: chi-square with the equivalent degrees of freedom of SP 1065
(section 5.2.3, "simple" formulas) for the noise type the local log-log slope shows
(-1 white PM / quantisation, -1/2 white FM / random walk of angle, 0 flicker FM / bias
instability, +1/2 random walk FM / rate random walk).
"""

from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from scipy.special import gammaincinv

from bench.errors import InputError

#: Coverage of the reported interval: +-1 sigma of a normal distribution.
CI_COVERAGE = 0.682689492137
#: A tau is computed only with at least this many independent clusters (N / m): beyond, the estimate is noise.
MIN_CLUSTERS = 4
_BLOCK = 1 << 13          # samples per block of the second-difference pass: 4 x 64 kB, in L2 (best of 2k..256k)
#: Local slopes of ADEV in log-log and the noise type each stands for.
SLOPES = {-1.0: "white PM (quantisation)", -0.5: "white FM (random walk of angle/velocity)",
          0.0: "flicker FM (bias instability)", 0.5: "random walk FM (rate random walk)"}


class AllanError(InputError):
    """A series the Allan deviation cannot be computed from (too short, not finite, a bad rate)."""


@dataclass(frozen=True)
class AllanCurve:
    """One channel's overlapping Allan deviation: `adev` at `tau_s`, in the series' own unit."""

    tau_s: np.ndarray
    adev: np.ndarray
    m: np.ndarray            # cluster size in samples
    edf: np.ndarray          # equivalent degrees of freedom of each AVAR estimate
    adev_low: np.ndarray     # +-1 sigma (68.3 %) chi-square interval
    adev_high: np.ndarray
    slope_noise: np.ndarray  # local slope the EDF assumed (-1, -0.5, 0, 0.5)
    rate_hz: float
    n_samples: int


def cluster_sizes(n_samples: int, points_per_octave: int = 1, min_clusters: int = MIN_CLUSTERS) -> np.ndarray:
    """Cluster sizes m (samples): octave-spaced 1, 2, 4, ... (denser with `points_per_octave`), m <= N / 4."""
    if points_per_octave < 1:
        raise AllanError(f"points per octave must be >= 1, got {points_per_octave}")
    m_max = n_samples // min_clusters
    if m_max < 1:
        raise AllanError(f"{n_samples} samples: too few for an Allan deviation (at least {min_clusters})")
    top = math.log2(m_max)
    steps = np.arange(0, int(math.floor(top * points_per_octave + 1e-9)) + 1) / points_per_octave
    return np.unique(np.floor(2.0 ** steps + 1e-9).astype(np.int64))


def integrate(y: np.ndarray, rate_hz: float) -> np.ndarray:
    """The "phase" of a rate series as allantools forms it: mean removed, cumulative sum / rate, 0 first."""
    y = np.asarray(y, dtype=np.float64)
    x = np.empty(len(y) + 1)
    x[0] = 0.0
    body = x[1:]
    np.subtract(y, y.mean(), out=body)        # in place: no full-length temporaries
    np.cumsum(body, out=body)
    body *= 1.0 / rate_hz
    return x


def _sum_second_differences(x: np.ndarray, m: int) -> float:
    """sum_k (x[k+2m] - 2 x[k+m] + x[k])^2 over k in [0, len(x) - 2m), block by block."""
    n = len(x) - 2 * m
    total = 0.0
    d = np.empty(min(_BLOCK, n))
    for start in range(0, n, _BLOCK):
        stop = min(start + _BLOCK, n)
        block = d[:stop - start]
        np.multiply(x[start + m:stop + m], -2.0, out=block)
        block += x[start + 2 * m:stop + 2 * m]
        block += x[start:stop]
        total += float(np.dot(block, block))
    return total


def oadev_of_phase(x: np.ndarray, rate_hz: float, m: np.ndarray) -> np.ndarray:
    """Overlapping ADEV of phase `x` at cluster sizes `m` (allantools' `calc_adev_phase`, stride 1)."""
    out = np.empty(len(m))
    for i, mj in enumerate(m):
        n = len(x) - 2 * int(mj)
        out[i] = math.sqrt(_sum_second_differences(x, int(mj)) / (2.0 * n)) / int(mj) * rate_hz
    return out


def _edf(n_phase: int, m: int, slope: float) -> float:
    """Equivalent degrees of freedom of an overlapping AVAR estimate (SP 1065, 5.2.3 simple formulas)."""
    n = float(n_phase)
    if slope <= -0.75:     # white PM
        edf = (n + 1) * (n - 2 * m) / (2 * (n - m))
    elif slope <= -0.25:   # white FM
        edf = (3 * (n - 1) / (2 * m) - 2 * (n - 2) / n) * 4 * m * m / (4 * m * m + 5)
    elif slope <= 0.25:    # flicker FM
        edf = 2 * (n - 2) ** 2 / (2.3 * n - 4.9) if m == 1 else 5 * n * n / (4 * m * (n + 3 * m))
    else:                  # random walk FM
        edf = (n - 2) / m * ((n - 1) ** 2 - 3 * m * (n - 1) + 4 * m * m) / (n - 3) ** 2
    return max(edf, 1.0)


def local_slopes(tau_s: np.ndarray, adev: np.ndarray) -> np.ndarray:
    """d log(adev) / d log(tau) at each point (central differences; one-sided at the ends)."""
    if len(tau_s) < 2:
        return np.full(len(tau_s), -0.5)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.gradient(np.log(np.maximum(adev, 1e-300)), np.log(tau_s))


def confidence(adev: np.ndarray, edf: np.ndarray, coverage: float = CI_COVERAGE) -> tuple[np.ndarray, np.ndarray]:
    """Chi-square interval of ADEV: sqrt(AVAR * edf / chi2_{(1+c)/2}), sqrt(AVAR * edf / chi2_{(1-c)/2})."""
    # chi2.ppf(q, edf) = 2 gammaincinv(edf / 2, q); scipy.special imports in a fraction of scipy.stats' time
    upper_q = 2.0 * gammaincinv(edf / 2.0, (1 + coverage) / 2)
    lower_q = 2.0 * gammaincinv(edf / 2.0, (1 - coverage) / 2)
    return adev * np.sqrt(edf / upper_q), adev * np.sqrt(edf / lower_q)


def allan_curve(y: np.ndarray, rate_hz: float, *, points_per_octave: int = 1,
                m: np.ndarray | None = None) -> AllanCurve:
    """Overlapping ADEV of one rate series at octave-spaced (or denser) cluster times, with +-1 sigma intervals."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise AllanError(f"sample rate must be a positive number of Hz, got {rate_hz!r}")
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1:
        raise AllanError(f"one channel at a time: got an array of shape {y.shape}")
    if not np.all(np.isfinite(y)):
        raise AllanError("the series holds values that are not finite numbers")
    sizes = cluster_sizes(len(y), points_per_octave) if m is None else np.asarray(m, dtype=np.int64)
    x = integrate(y, rate_hz)
    return _curve(x, rate_hz, sizes, len(y))


def _curve(x: np.ndarray, rate_hz: float, sizes: np.ndarray, n_samples: int) -> AllanCurve:
    adev = oadev_of_phase(x, rate_hz, sizes)
    tau_s = sizes / rate_hz
    slopes = local_slopes(tau_s, adev)
    snapped = np.array([min(SLOPES, key=lambda s: abs(s - v)) if np.isfinite(v) else -0.5 for v in slopes])
    # White PM (quantisation) shows at the shortest taus only; its EDF (~N/2 whatever m) is never right for a
    # long-tau point whose few clusters happen to fall steeply.
    leading = int(np.argmax(snapped != -1.0)) if np.any(snapped != -1.0) else len(snapped)
    snapped[leading:] = np.maximum(snapped[leading:], -0.5)
    edf = np.array([_edf(len(x), int(mj), s) for mj, s in zip(sizes, snapped)])
    low, high = confidence(adev, edf)
    return AllanCurve(tau_s, adev, sizes, edf, low, high, snapped, float(rate_hz), n_samples)


def allan_curves(channels: np.ndarray, rate_hz: float, *, points_per_octave: int = 1,
                 threads: int = 2) -> list[AllanCurve]:
    """`allan_curve` of each column of `channels` (n, k), the columns on `threads` threads."""
    data = np.asarray(channels)
    if data.ndim != 2:
        raise AllanError(f"channels must be an (n, k) array, got shape {data.shape}")
    with ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="allan-channel") as pool:
        return list(pool.map(lambda k: allan_curve(data[:, k], rate_hz, points_per_octave=points_per_octave),
                             range(data.shape[1])))


__all__ = ["CI_COVERAGE", "MIN_CLUSTERS", "SLOPES", "AllanCurve", "AllanError", "allan_curve", "allan_curves",
           "cluster_sizes", "confidence", "integrate", "local_slopes", "oadev_of_phase"]
