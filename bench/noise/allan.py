"""Overlapping Allan deviation with confidence intervals (IEEE Std 952-1997 Annex C; NIST SP 1065).

The input is a rate series `y` (one channel: deg/h for a gyro, ug for an
accelerometer) sampled at `rate_hz`. As `allantools.oadev(..., data_type="freq")`
does, the mean is removed, the series integrated to a "phase" `x` (zero prepended)
and, for each cluster size `m` (tau = m / rate_hz),

    AVAR(tau) = sum_k (x[k+2m] - 2 x[k+m] + x[k])^2 / (2 tau^2 (N - 2m)),  N = len(x).

The phase of the channels is one (k, N + 1) float64 array, one contiguous row per
channel, accumulated block by block (`PhaseAccumulator`: a streaming reader hands it each
decoded block; nothing else of the record is kept, 8 bytes per sample and channel). The
sum of squared second differences at size m comes from first differences e_m(k) =
x[k+m] - x[k]: d_m(k)^2 = 2 e_m(k)^2 + 2 e_m(k+m)^2 - e_2m(k)^2, so each lag costs one
subtraction and one dot product (segment sums of e_m^2), and octave sizes share their
lags (2m is the next size): half the passes over the data of the direct form. Where
that identity would cancel (a drift far above the noise: the first differences much
larger than the second), the size is summed directly, so float64 keeps ~1e-10 or
better. The passes run over cache-sized blocks of k with the lags inner (the stretch
x[k + 2m] of one lag is the stretch x[k + m'] of the next), each channel's record split
over threads (numpy releases the GIL).

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
_BLOCK = 1 << 13          # samples per block of the sums: 64 kB per stretch (2k: call overhead; 16k+: 30x slower here)
_CANCELLATION = 1e4       # largest (sum of the identity's terms) / result before a size is summed directly
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


class PhaseAccumulator:
    """The phase of k channels, built from blocks of rate samples handed in order (a streaming log reader's).

    `add(block)` takes an (n, k) block (1-D for one channel) and appends its running sum; the first
    block's mean is taken off every sample (allantools takes off the whole record's mean, which it knows
    in advance: a constant offset cancels in every second difference, and any offset near the mean keeps
    the running sum small enough for float64), unless `offset` is given. The sum is kept in sample units
    (the 1 / rate is applied to the deviations). `capacity`, the number of samples expected (e.g. a dwell's
    counter window), avoids regrowing the array. Memory: 8 bytes per sample and channel."""

    def __init__(self, rate_hz: float, n_channels: int, *, offset: np.ndarray | None = None, capacity: int = 0,
                 threads: int = 2):
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise AllanError(f"sample rate must be a positive number of Hz, got {rate_hz!r}")
        self.rate_hz, self.n_channels, self.threads = float(rate_hz), int(n_channels), int(threads)
        self._offset = None if offset is None else np.asarray(offset, dtype=np.float64).reshape(self.n_channels)
        self._phase = np.zeros((self.n_channels, max(int(capacity), 0) + 1))
        self.n_samples = 0

    def add(self, block: np.ndarray) -> None:
        """Append an (n, k) block of rate samples (AllanError if not finite or of another width)."""
        block = np.asarray(block, dtype=np.float64)
        if block.ndim == 1 and self.n_channels == 1:
            block = block[:, None]
        if block.ndim != 2 or block.shape[1] != self.n_channels:
            raise AllanError(f"a block of {self.n_channels} channel(s) expected, got an array of shape {block.shape}")
        n = len(block)
        if n == 0:
            return
        offset = block.mean(axis=0) if self._offset is None else self._offset
        start, need = self.n_samples + 1, self.n_samples + n + 1
        if need > self._phase.shape[1]:
            grown = np.empty((self.n_channels, max(need, 2 * self._phase.shape[1])))
            grown[:, :start] = self._phase[:, :start]
            self._phase = grown

        def channel(k: int) -> None:
            row = self._phase[k, start:need]
            with np.errstate(invalid="ignore", over="ignore"):     # not finite: refused below
                np.subtract(block[:, k], offset[k], out=row)
                row[0] += self._phase[k, start - 1]
                np.cumsum(row, out=row)

        if self.threads > 1 and n * self.n_channels >= 1 << 20:
            with ThreadPoolExecutor(max_workers=self.threads, thread_name_prefix="allan-channel") as pool:
                list(pool.map(channel, range(self.n_channels)))
        else:
            for k in range(self.n_channels):
                channel(k)
        # a value that is not finite (or a sum that overflows) makes every later running sum inf or nan: the
        # block's last one tells, without a pass of its own
        if not np.all(np.isfinite(self._phase[:, need - 1])):
            raise AllanError("the series holds values that are not finite numbers")
        self._offset = offset
        self.n_samples += n

    def add_scaled(self, columns: list[np.ndarray], factors: np.ndarray) -> None:
        """Append k columns of n samples given as `columns[j] * factors[0, j] / factors[1, j]` (e.g. counts per
        sample x rate / (scale x unit)), each computed straight into its phase row: what `add` of the (n, k)
        block of those values does, bit for bit, without the block. Needs the offset (given, or from an
        earlier `add`)."""
        if self._offset is None:
            raise AllanError("add_scaled needs the offset: give it, or add() a first block")
        if len(columns) != self.n_channels:
            raise AllanError(f"{self.n_channels} column(s) expected, got {len(columns)}")
        n = len(columns[0])
        if n == 0:
            return
        start, need = self.n_samples + 1, self.n_samples + n + 1
        if need > self._phase.shape[1]:
            grown = np.empty((self.n_channels, max(need, 2 * self._phase.shape[1])))
            grown[:, :start] = self._phase[:, :start]
            self._phase = grown
        with np.errstate(invalid="ignore", over="ignore"):     # not finite: refused below
            for k, column in enumerate(columns):
                row = self._phase[k, start:need]
                np.multiply(column, factors[0, k], out=row)
                row /= factors[1, k]
                row -= self._offset[k]
                row[0] += self._phase[k, start - 1]
                np.cumsum(row, out=row)
        if not np.all(np.isfinite(self._phase[:, need - 1])):
            raise AllanError("the series holds values that are not finite numbers")
        self.n_samples += n

    @property
    def phase(self) -> np.ndarray:
        """(k, n + 1) running sums (sample units: x / rate is allantools' phase), 0 first."""
        return self._phase[:, :self.n_samples + 1]

    def stretch(self, start: int, stop: int) -> "PhaseAccumulator":
        """Samples [start, stop) as an accumulator of their own, sharing this one's phase (no copy): every
        sum is of differences of the phase, so what was summed before `start` does not matter."""
        if not 0 <= start <= stop <= self.n_samples:
            raise AllanError(f"samples {start}..{stop} are not within the {self.n_samples} held")
        part = PhaseAccumulator(self.rate_hz, self.n_channels, offset=self._offset, threads=self.threads)
        part._phase, part.n_samples = self._phase[:, start:stop + 1], stop - start
        return part

    def curves(self, *, points_per_octave: int = 1, m: np.ndarray | None = None,
               threads: int = 2) -> list["AllanCurve"]:
        """The overlapping Allan deviation of each channel with +-1 sigma intervals."""
        sizes = cluster_sizes(self.n_samples, points_per_octave) if m is None else np.asarray(m, dtype=np.int64)
        sums = second_difference_sums(self.phase, sizes, threads=threads)
        n_terms = (self.n_samples + 1 - 2 * sizes).astype(float)
        adev = np.sqrt(sums / (2.0 * n_terms)[None, :]) / sizes[None, :]
        return [_curve(adev[k], self.n_samples + 1, self.rate_hz, sizes, self.n_samples)
                for k in range(self.n_channels)]


def _direct_sums(x: np.ndarray, sizes: list[int], lo: int, hi: int) -> np.ndarray:
    """Sum over k in [lo, hi) of (x[k+2m] - 2 x[k+m] + x[k])^2 for each size m of one channel, the sizes inner."""
    out = np.zeros(len(sizes))
    buffer = np.empty(_BLOCK)
    stops = [min(hi, len(x) - 2 * m) for m in sizes]
    for start in range(lo, max(stops, default=lo), _BLOCK):
        for j, m in enumerate(sizes):
            stop = min(start + _BLOCK, stops[j])
            if stop <= start:
                continue
            d = buffer[:stop - start]
            np.multiply(x[start + m:stop + m], -2.0, out=d)
            d += x[start + 2 * m:stop + 2 * m]
            d += x[start:stop]
            out[j] += float(np.dot(d, d))
    return out


def _difference_segments(x: np.ndarray, lags: list[int], lo: int, hi: int) -> np.ndarray:
    """(len(lags), 3): for each lag L the sums of e_L(k)^2 = (x[k+L] - x[k])^2 over k in [0, L), [L, n-2L) and
    [n-2L, n-L) (n = len(x); empty where they cross), restricted to k in [lo, hi); the lags inner."""
    n_x = len(x)
    out = np.zeros((len(lags), 3))
    buffer = np.empty(_BLOCK)
    bounds = []
    for lag in lags:
        end = n_x - lag
        first = min(lag, end)
        bounds.append((first, min(max(n_x - 2 * lag, first), end), end))
    for start in range(lo, min(hi, max((b[2] for b in bounds), default=lo)), _BLOCK):
        for j, lag in enumerate(lags):
            first, second, end = bounds[j]
            stop = min(start + _BLOCK, hi, end)
            if stop <= start:
                continue
            e = buffer[:stop - start]
            np.subtract(x[start + lag:stop + lag], x[start:stop], out=e)
            if first <= start and stop <= second:          # almost every block: all in the middle segment
                out[j, 1] += float(np.dot(e, e))
                continue
            for seg, (a, b) in enumerate(((0, first), (first, second), (second, end))):
                a, b = max(a, start), min(b, stop)
                if b > a:
                    part = e[a - start:b - start]
                    out[j, seg] += float(np.dot(part, part))
    return out


def _channel_sums(x: np.ndarray, sizes: list[int], ranges: list[tuple[int, int]], pool) -> np.ndarray:
    """Sum of squared second differences of one channel at each size, from first differences (see below)."""
    # With e_m(k) = x[k+m] - x[k]: d_m(k) = e_m(k+m) - e_m(k) and e_2m(k) = e_m(k+m) + e_m(k), so
    # d_m(k)^2 = 2 e_m(k)^2 + 2 e_m(k+m)^2 - e_2m(k)^2 and the sum over k in [0, n-2m) is
    # 2 (A + B) + 2 (B + C) - E_2m with A, B, C the sums of e_m^2 over [0, m), [m, n-2m), [n-2m, n-m) and E_2m
    # the sum of e_2m^2 over its whole range: one difference and one dot product per lag instead of three
    # operations and a dot product per size; octave sizes share their lags (2m is the next size).
    lags = sorted(set(sizes) | {2 * m for m in sizes})
    if pool is None:
        parts = [_difference_segments(x, lags, lo, hi) for lo, hi in ranges]
    else:
        parts = list(pool.map(lambda r: _difference_segments(x, lags, r[0], r[1]), ranges))
    seg = np.sum(parts, axis=0)
    row = {lag: i for i, lag in enumerate(lags)}
    out = np.empty(len(sizes))
    for j, m in enumerate(sizes):
        a, b, c = seg[row[m]]
        e2 = float(seg[row[2 * m]].sum())
        total = 2.0 * (a + b) + 2.0 * (b + c)
        result = total - e2
        # the identity cancels when the first differences are much larger than the second (a drift far above the
        # noise): beyond 1e4 (float64 then keeps ~1e-11) this size is summed directly
        if not result > 0 or (total + e2) > _CANCELLATION * result:
            result = float(_direct_sums(x, [m], 0, len(x))[0])
        out[j] = result
    return out


def second_difference_sums(x: np.ndarray, sizes: np.ndarray, *, threads: int = 2) -> np.ndarray:
    """(k, len(sizes)) sums of squared second differences of the phase `x` (k, n) (or (n,): then (1, len(sizes))),
    each channel's record split over `threads` threads."""
    x = np.asarray(x, dtype=np.float64)
    x = x[None, :] if x.ndim == 1 else x
    channels, n_x = x.shape
    sizes_list = [int(m) for m in sizes]
    out = np.zeros((channels, len(sizes_list)))
    if not sizes_list:
        return out
    if 2 * max(sizes_list) >= n_x:
        raise AllanError(f"cluster size {max(sizes_list)} too large for {n_x - 1} samples")
    parts = max(1, min(int(threads), n_x // (4 * _BLOCK)))
    edges = np.linspace(0, n_x, parts + 1).astype(np.int64)
    ranges = [(int(lo), int(hi)) for lo, hi in zip(edges[:-1], edges[1:])]
    if parts == 1:
        for k in range(channels):
            out[k] = _channel_sums(x[k], sizes_list, ranges, None)
        return out
    with ThreadPoolExecutor(max_workers=parts, thread_name_prefix="allan-part") as pool:
        for k in range(channels):
            out[k] = _channel_sums(x[k], sizes_list, ranges, pool)
    return out


def oadev_of_phase(x: np.ndarray, rate_hz: float, m: np.ndarray) -> np.ndarray:
    """Overlapping ADEV of phase `x` (1-D, allantools' units) at cluster sizes `m` (`calc_adev_phase`, stride 1)."""
    sizes = np.asarray(m, dtype=np.int64)
    sums = second_difference_sums(np.asarray(x, dtype=np.float64), sizes, threads=1)[0]
    return np.sqrt(sums / (2.0 * (len(x) - 2 * sizes))) / sizes * rate_hz


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
    y = np.asarray(y, dtype=np.float64)
    if y.ndim != 1:
        raise AllanError(f"one channel at a time: got an array of shape {y.shape}")
    return allan_curves(y[:, None], rate_hz, points_per_octave=points_per_octave, m=m, threads=1)[0]


def _curve(adev: np.ndarray, n_phase: int, rate_hz: float, sizes: np.ndarray, n_samples: int) -> AllanCurve:
    tau_s = sizes / rate_hz
    slopes = local_slopes(tau_s, adev)
    snapped = np.array([min(SLOPES, key=lambda s: abs(s - v)) if np.isfinite(v) else -0.5 for v in slopes])
    # White PM (quantisation) shows at the shortest taus only; its EDF (~N/2 whatever m) is never right for a
    # long-tau point whose few clusters happen to fall steeply.
    leading = int(np.argmax(snapped != -1.0)) if np.any(snapped != -1.0) else len(snapped)
    snapped[leading:] = np.maximum(snapped[leading:], -0.5)
    edf = np.array([_edf(n_phase, int(mj), s) for mj, s in zip(sizes, snapped)])
    low, high = confidence(adev, edf)
    return AllanCurve(tau_s, adev, sizes, edf, low, high, snapped, float(rate_hz), n_samples)


def allan_curves(channels: np.ndarray, rate_hz: float, *, points_per_octave: int = 1, m: np.ndarray | None = None,
                 threads: int = 2) -> list[AllanCurve]:
    """`allan_curve` of each column of `channels` (n, k), the whole record's mean taken off as allantools does."""
    data = np.asarray(channels, dtype=np.float64)
    if data.ndim != 2:
        raise AllanError(f"channels must be an (n, k) array, got shape {data.shape}")
    offset = data.mean(axis=0)
    if not np.all(np.isfinite(offset)):
        raise AllanError("the series holds values that are not finite numbers")
    acc = PhaseAccumulator(rate_hz, data.shape[1], offset=offset, capacity=len(data), threads=threads)
    acc.add(data)
    return acc.curves(points_per_octave=points_per_octave, m=m, threads=threads)


__all__ = ["CI_COVERAGE", "MIN_CLUSTERS", "SLOPES", "AllanCurve", "AllanError", "PhaseAccumulator", "allan_curve",
           "allan_curves", "cluster_sizes", "confidence", "integrate", "local_slopes", "oadev_of_phase",
           "second_difference_sums"]
