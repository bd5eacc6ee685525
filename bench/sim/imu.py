"""The simulated IMU: per-sample gyro and accelerometer increments from a SimTable.

Sample n (0-based) covers [start + n/rate, start + (n+1)/rate]; its increment is the
integral of the model output (docs/explanation/model.md#imu-model, counts/s) over that interval, with
3-point Gauss-Legendre per interval (split at the table's piece boundaries, so a
rest-to-rest turn integrates exactly), plus noise on the input side
(`F = Kg*(Eg.w + D0 + n)`, `J = Ka*(Ea.f + K0 + n)`) and optional quantisation.
Successive `generate` calls continue seamlessly and are bit-identical to one call.

With an `ImuThermal` the coefficients follow the case temperature (`bench.sim.thermal`:
first order behind an ambient), evaluated at every quadrature node, and the samples
carry the case temperature the IMU reports; without one, nothing of this runs.

With `HigherOrderTerms` (bench.model.higher_order) the outputs gain the higher-order errors, the accelerometers
see the specific force at their own lever arms and late by the time offset; without them (or all zero), nothing
of this runs and the outputs are bit for bit those of the 30-coefficient model.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import ImuCoefficients, NoiseModel
from bench.model.thermal import ImuThermal
from bench.model.units import DEG, DEG_PER_HOUR, MICRO_G
from bench.sim.first_order import first_order_filter
from bench.sim.table import SimTable
from bench.sim.thermal import Ambient, CaseTemperature

COUNTER_MODULUS = 2 ** 32
_GL_X, _GL_W = np.polynomial.legendre.leggauss(3)
# Independent random streams, so that switching one noise term off leaves the others unchanged.
_STREAMS = ("gyro_white", "acc_white", "gyro_gm", "acc_gm", "quantise", "gyro_rrw", "acc_rrw")
#: half-step of the central difference that gives the body's angular acceleration (tangential lever-arm term), s:
#: small against a sample (Gauss nodes stand >= 11 % of an interval from its ends), large against rounding
_RATE_DERIVATIVE_STEP_S = 1e-6


@dataclass
class ImuSamples:
    """What the simulated IMU *produces*: a block of true samples before any wire.

    Increments are per sample, in output counts; `time_s` is the simulated time. The
    three sample arrays of the project differ by where they stand in the data flow:
    `ImuSamples` (here) is the simulator's output, before it is encoded into CAN frames;
    `drivers.imu.ImuSampleBlock` is what the driver *decodes* from frames (live, or in bulk
    from a log's `/can/raw`: unwrapped counter, receive time, temperature, status);
    `bench.log.reader.ImuRecords` is what the log's derived `/imu/samples` topic holds
    (possibly decimated; for people and Foxglove, not for the solver).
    """

    counter: np.ndarray      # (n,) int64, the IMU's own sample counter: 0 for the first sample, wraps at 2**32
    time_s: np.ndarray       # (n,) end time of each sample interval, simulated seconds
    gyro_counts: np.ndarray  # (n, 3) per-sample increments (integral-valued when quantised)
    acc_counts: np.ndarray   # (n, 3)
    rate_hz: float
    #: (n,) the case temperature at the end of each sample, degC; None: the IMU has no thermal model
    temperature_c: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.counter)

    @property
    def gyro_rate(self) -> np.ndarray:
        """Gyro outputs as rates, counts/s."""
        return self.gyro_counts * self.rate_hz

    @property
    def acc_rate(self) -> np.ndarray:
        """Accelerometer outputs as rates, counts/s."""
        return self.acc_counts * self.rate_hz

    @classmethod
    def concatenate(cls, blocks: list["ImuSamples"]) -> "ImuSamples":
        """Join consecutive blocks of one IMU (at least one block)."""
        temps = [b.temperature_c for b in blocks if b.temperature_c is not None]
        return cls(np.concatenate([b.counter for b in blocks]), np.concatenate([b.time_s for b in blocks]),
                   np.concatenate([b.gyro_counts for b in blocks]), np.concatenate([b.acc_counts for b in blocks]),
                   blocks[0].rate_hz, np.concatenate(temps) if len(temps) == len(blocks) else None)


class _GaussMarkov:
    """First-order Gauss-Markov noise per channel: exact AR(1), stationary start, state carried."""

    def __init__(self, sigma: float, tau: float, dt: float, rng: np.random.Generator):
        self.sigma, self.rng = sigma, rng
        self.phi = math.exp(-dt / tau) if tau > 0 else 0.0
        self.gain = sigma * math.sqrt(1.0 - self.phi * self.phi)
        # the carried state is phi*y[-1] (lfilter's zi): y[0] = gain*w[0] + phi*y[-1], y[-1] ~ N(0, sigma^2).
        self.zi = (self.phi * sigma * rng.standard_normal(3))[None, :] if sigma > 0 else None

    def draw(self, n: int) -> np.ndarray:
        if self.zi is None or n == 0:
            return np.zeros((n, 3))
        y, self.zi = first_order_filter(self.gain, self.phi, self.rng.standard_normal((n, 3)), self.zi)
        return y


class _RandomWalk:
    """A bias that random-walks from 0 per channel (rate random walk): state carried across calls."""

    def __init__(self, step_sigma: float, rng: np.random.Generator):
        self.step_sigma, self.rng = step_sigma, rng
        self.state = np.zeros(3)

    def draw(self, n: int) -> np.ndarray:
        if self.step_sigma <= 0 or n == 0:
            return np.zeros((n, 3))
        walk = self.state + np.cumsum(self.step_sigma * self.rng.standard_normal((n, 3)), axis=0)
        self.state = walk[-1].copy()
        return walk


class _Quantiser:
    """Integer counts per sample: accumulated output = floor(r0 + cumulative true count)."""

    def __init__(self, rng: np.random.Generator):
        self.total = rng.random(3)            # r0 + cumulative true count, carried as is
        self.floor = np.floor(self.total)     # accumulated output so far (0 at the start)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if len(x) == 0:
            return x
        total = np.cumsum(np.vstack([self.total, x]), axis=0)[1:]
        floors = np.floor(total)
        out = np.diff(np.vstack([self.floor, floors]), axis=0)
        self.total, self.floor = total[-1].copy(), floors[-1].copy()
        return out


_NO_NOISE = NoiseModel.off()


class SimImu:
    """Signal generator of a simulated IMU mounted on a `SimTable`'s inner frame."""

    def __init__(self, coefficients: ImuCoefficients, noise: NoiseModel = _NO_NOISE,
                 rate_hz: float = 1000.0, seed: int = 0, start_time_s: float = 0.0,
                 thermal: ImuThermal | None = None, ambient_c: Ambient | None = None,
                 higher_order: HigherOrderTerms | None = None):
        """`coefficients` are the truth at `thermal.reference_c`; `ambient_c` (default
        `thermal.ambient_c`) drives the case temperature; `higher_order`: the errors beyond the 30 coefficients."""
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be positive, got {rate_hz}")
        self.coefficients, self.noise = coefficients, noise
        self.rate_hz, self.start_time_s = float(rate_hz), float(start_time_s)
        self._done = 0  # samples generated so far
        self.thermal = thermal
        self.higher_order = higher_order if higher_order is not None and higher_order.enabled else None
        self.case: CaseTemperature | None = None
        if thermal is not None:
            self.case = CaseTemperature(thermal.time_constant_s, thermal.ambient_c if ambient_c is None else ambient_c,
                                        thermal.initial_c, self.start_time_s)
        self._grid: tuple[np.ndarray, np.ndarray] | None = None   # (times, case temperatures) of this block
        # (spawned children depend on their index only: adding streams at the end leaves the others as they were)
        seeds = np.random.SeedSequence(seed).spawn(len(_STREAMS))
        rngs = dict(zip(_STREAMS, (np.random.default_rng(s) for s in seeds)))
        self._rng = rngs
        dt, tau = 1.0 / self.rate_hz, noise.correlation_time_s
        self._gyro_gm = _GaussMarkov(noise.gyro_bias_instability_dph * DEG_PER_HOUR, tau, dt, rngs["gyro_gm"])
        self._acc_gm = _GaussMarkov(noise.acc_bias_instability_ug * MICRO_G, tau, dt, rngs["acc_gm"])
        # Rate random walk K (per sqrt(h)): a step of K / 60 * sqrt(dt) per sample (1/sqrt(h) = 1/60 per sqrt(s)).
        self._gyro_rw = _RandomWalk(noise.gyro_rrw_dph_rt_h * DEG_PER_HOUR / 60.0 * math.sqrt(dt), rngs["gyro_rrw"])
        self._acc_rw = _RandomWalk(noise.acc_rrw_ug_rt_h * MICRO_G / 60.0 * math.sqrt(dt), rngs["acc_rrw"])
        # White noise, 1-sigma per sample in input units (rad/s, m/s^2).
        self._gyro_sigma = noise.gyro_arw_deg_rt_h * DEG / 60.0 * math.sqrt(self.rate_hz)
        self._acc_sigma = noise.acc_vrw_ug_rt_hz * MICRO_G * math.sqrt(self.rate_hz)
        if noise.quantise:
            self._q_gyro, self._q_acc = _Quantiser(rngs["quantise"]), _Quantiser(rngs["quantise"])

    @property
    def samples_generated(self) -> int:
        return self._done

    @property
    def last_time_s(self) -> float:
        """End time of the last generated sample (the start time before any)."""
        return float(self._time(self._done))

    def _time(self, n):
        return self.start_time_s + np.asarray(n, dtype=float) / self.rate_hz

    def _integrate(self, table: SimTable, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Integrals of the gyro and accel outputs (counts) over each [a_k, b_k], 3-point Gauss-Legendre."""
        half = 0.5 * (b - a)
        nodes = (0.5 * (a + b))[:, None] + half[:, None] * _GL_X
        w = half[:, None] * _GL_W                                        # (n, 3 nodes)
        w_b, f_b = table.body_rate_and_specific_force(nodes.reshape(-1))
        if self.higher_order is not None:
            gyro, acc = self._higher_order_outputs(table, nodes.reshape(-1), w_b, f_b, self.higher_order)
            gyro, acc = gyro.reshape(len(a), 3, 3), acc.reshape(len(a), 3, 3)
        elif self.thermal is None:
            gyro = self.coefficients.gyro_output(w_b).reshape(len(a), 3, 3)
            acc = self.coefficients.acc_output(f_b).reshape(len(a), 3, 3)
        else:
            gyro, acc = self._thermal_outputs(nodes.reshape(-1), w_b, f_b)
            gyro, acc = gyro.reshape(len(a), 3, 3), acc.reshape(len(a), 3, 3)
        return np.einsum("kn,knc->kc", w, gyro), np.einsum("kn,knc->kc", w, acc)

    def _thermal_outputs(self, times: np.ndarray, w_b: np.ndarray, f_b: np.ndarray):
        """Outputs with the coefficients at the case temperature of each time (linear between the
        block's sample boundaries: the case moves on a scale of minutes, a sample lasts milliseconds)."""
        assert self.thermal is not None and self._grid is not None
        temps = np.interp(times, *self._grid)
        kg, d0, eg, ka, k0, ea = self.thermal.arrays_at(self.coefficients, temps)
        gyro = np.einsum("mij,mj->mi", kg[:, :, None] * eg, w_b) + kg * d0
        acc = np.einsum("mij,mj->mi", ka[:, :, None] * ea, f_b) + ka * k0
        return gyro, acc

    def _coefficient_arrays(self, times: np.ndarray):
        """(kg, d0, eg, ka, k0, ea) per time: (m, 3) and (m, 3, 3), at the case temperature if thermal."""
        if self.thermal is not None:
            assert self._grid is not None
            return self.thermal.arrays_at(self.coefficients, np.interp(times, *self._grid))
        c, m = self.coefficients, len(times)
        return tuple(np.broadcast_to(x, (m,) + x.shape) for x in (c.gyro_scale, c.gyro_bias, c.gyro_axes,
                                                                  c.acc_scale, c.acc_bias, c.acc_axes))

    def _higher_order_outputs(self, table: SimTable, times: np.ndarray, w_b: np.ndarray, f_b: np.ndarray,
                              terms: HigherOrderTerms):
        """Gyro and accel outputs (counts/s) at times with the higher-order terms (bench.model.higher_order)."""
        kg, d0, eg, ka, k0, ea = self._coefficient_arrays(times)
        # The time offset delays the accelerometers (> 0) or the gyros (< 0): never a look ahead, as the table's
        # motion after the time generated may not be commanded yet.
        gyro_lag, acc_lag = max(-terms.time_offset_s, 0.0), max(terms.time_offset_s, 0.0)
        w_gyro, f_gyro = (w_b, f_b) if gyro_lag == 0.0 else table.body_rate_and_specific_force(times - gyro_lag)
        gyro_input = np.einsum("msj,mj->ms", eg, w_gyro)
        gyro = kg * (gyro_input + terms.gyro_error(gyro_input, f_gyro) + d0)
        # The accelerometers, each at its own place.
        late = times - acc_lag
        w_late, f_late = (w_b, f_b) if acc_lag == 0.0 else table.body_rate_and_specific_force(late)
        force = np.broadcast_to(f_late[:, None, :], (len(times), 3, 3))
        if terms.has_lever_arms:
            h = _RATE_DERIVATIVE_STEP_S
            rate_derivative = (table.body_rate(late + h) - table.body_rate(late - h)) / (2.0 * h)
            force = force + terms.lever_arm_force(w_late, rate_derivative)
        acc_input = np.einsum("msj,msj->ms", ea, force)
        acc = ka * (acc_input + terms.acc_error(acc_input, force) + k0)
        return gyro, acc

    def _true_increments(self, table: SimTable, a: np.ndarray, b: np.ndarray):
        gyro, acc = self._integrate(table, a, b)
        # Split the intervals that contain a piece boundary (a kink in the rate) at it.
        bounds = table.piece_starts()
        lo, hi = np.searchsorted(bounds, a, side="right"), np.searchsorted(bounds, b, side="left")
        split = np.nonzero(hi > lo)[0]
        if len(split):
            idx, sa, sb = [], [], []
            for k in split:
                edges = np.concatenate([[a[k]], bounds[lo[k]:hi[k]], [b[k]]])
                idx += [k] * (len(edges) - 1)
                sa.append(edges[:-1])
                sb.append(edges[1:])
            g, c = self._integrate(table, np.concatenate(sa), np.concatenate(sb))
            gyro[split], acc[split] = 0.0, 0.0
            np.add.at(gyro, idx, g)
            np.add.at(acc, idx, c)
        return gyro, acc

    def generate(self, table: SimTable, t_end: float) -> ImuSamples:
        """All samples whose interval ends in (last generated time, t_end]."""
        total = max(self._done, int(math.floor((t_end - self.start_time_s) * self.rate_hz + 1e-9)))
        n_idx = np.arange(self._done, total, dtype=np.int64)
        self._done = total
        a, b = self._time(n_idx), self._time(n_idx + 1)
        n = len(n_idx)
        temperature = None
        if self.case is not None and n:
            t0, temp0 = self.case.time_s, self.case.temperature_c      # the block's first sample start
            temperature = self.case.advance(b)
            self._grid = (np.concatenate([[t0], b]), np.concatenate([[temp0], temperature]))
        elif self.case is not None:
            temperature = np.zeros(0)
        gyro, acc = self._true_increments(table, a, b) if n else (np.zeros((0, 3)), np.zeros((0, 3)))
        dt = 1.0 / self.rate_hz
        gyro_noise = self._gyro_gm.draw(n) + self._gyro_rw.draw(n)
        if self._gyro_sigma > 0:
            gyro_noise = gyro_noise + self._gyro_sigma * self._rng["gyro_white"].standard_normal((n, 3))
        acc_noise = self._acc_gm.draw(n) + self._acc_rw.draw(n)
        if self._acc_sigma > 0:
            acc_noise = acc_noise + self._acc_sigma * self._rng["acc_white"].standard_normal((n, 3))
        gyro = gyro + self.coefficients.gyro_scale * gyro_noise * dt
        acc = acc + self.coefficients.acc_scale * acc_noise * dt
        if self.noise.quantise:
            gyro, acc = self._q_gyro(gyro), self._q_acc(acc)
        return ImuSamples(n_idx % COUNTER_MODULUS, b, gyro, acc, self.rate_hz, temperature)
