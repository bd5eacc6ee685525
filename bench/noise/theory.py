"""The Allan deviation the simulated IMU's noise model should show, and what the fit should read from it.

The simulated IMU (`bench.sim.imu`) adds, per channel in input units: white noise
(ARW N / VRW), a first-order Gauss-Markov bias (1-sigma s, correlation time T), a
random-walk bias (K) and count quantisation. Their Allan variances add:

- white:        N^2 / tau
- Gauss-Markov: (s T / tau)^2 (2 tau / T - 3 + 4 exp(-tau/T) - exp(-2 tau/T))
  (IEEE 952 Annex C; rises as +1/2 slope for tau << T, falls as -1/2 for tau >> T,
  peaks at 0.617 s at tau = 1.89 T);
- rate random walk: K^2 tau / 3;
- quantisation: 3 Q^2 / tau^2 with Q = one count / sqrt(12) (the accumulated output is
  the floor of the true count: a uniform error of one count).

The Gauss-Markov bias is *not* IEEE 952's flicker (bias instability) noise, whose Allan
deviation is flat at 0.664 B. What the flat-region rule B = min ADEV / 0.664 reads
from a curve made by this model is `expected_bias_instability`: the minimum of the
total theoretical curve at the same taus over 0.664; alone (white noise and RRW far
below) that is 0.617 / 0.664 s = 0.929 s (`GM_TO_ALLAN_BI`).
"""

from __future__ import annotations

import math

import numpy as np

from bench.model.imu import ImuCoefficients, NoiseModel
from bench.model.units import DEG, HOUR, MICRO_G
from bench.noise.covariance import gauss_markov_avar
from bench.noise.fit import FLICKER_FACTOR, GM_PEAK_ADEV, GM_PEAK_TAU

#: What B = min ADEV / 0.664 reads from a Gauss-Markov bias alone, per unit sigma.
GM_TO_ALLAN_BI = GM_PEAK_ADEV / FLICKER_FACTOR


def channel_avar(tau_s: np.ndarray, *, white: float, gm_sigma: float, correlation_time_s: float, rrw: float,
                 q: float) -> np.ndarray:
    """Total Allan variance: white N (unit sqrt(s)), GM sigma (unit), RRW K (unit/sqrt(s)), quantisation Q (unit s)."""
    tau = np.asarray(tau_s, dtype=float)
    avar = white ** 2 / tau + rrw ** 2 * tau / 3.0 + 3.0 * q ** 2 / tau ** 2
    if gm_sigma > 0:
        avar = avar + gauss_markov_avar(tau, gm_sigma, correlation_time_s)
    return avar


def sim_channel_params(noise: NoiseModel, imu: ImuCoefficients) -> dict[str, dict[str, float]]:
    """Per channel (gyro_x..acc_z) the model parameters in the Allan units: deg/h for gyros, ug for accelerometers.

    white: N in unit sqrt(s) (ADEV at 1 s); gm_sigma: unit; rrw: K in unit / sqrt(s); q: unit s.
    """
    params = {}
    for k, axis in enumerate("xyz"):
        # one gyro count is 1 / gyro_scale rad (x 3600 / DEG in deg/h s); one accelerometer count
        # 1 / acc_scale m/s (/ MICRO_G in ug s)
        gyro_q = HOUR / DEG / float(imu.gyro_scale[k]) / math.sqrt(12.0) if noise.quantise else 0.0
        acc_q = 1.0 / MICRO_G / float(imu.acc_scale[k]) / math.sqrt(12.0) if noise.quantise else 0.0
        params[f"gyro_{axis}"] = dict(white=noise.gyro_arw_deg_rt_h * 60.0, gm_sigma=noise.gyro_bias_instability_dph,
                                      correlation_time_s=noise.correlation_time_s,
                                      rrw=noise.gyro_rrw_dph_rt_h / 60.0, q=gyro_q)
        params[f"acc_{axis}"] = dict(white=noise.acc_vrw_ug_rt_hz, gm_sigma=noise.acc_bias_instability_ug,
                                     correlation_time_s=noise.correlation_time_s,
                                     rrw=noise.acc_rrw_ug_rt_h / 60.0, q=acc_q)
    return params


def expected_bias_instability(tau_s: np.ndarray, params: dict[str, float]) -> float:
    """min over `tau_s` of the theoretical ADEV / 0.664: what the flat-region rule should read."""
    return float(np.sqrt(channel_avar(tau_s, **params)).min() / FLICKER_FACTOR)


__all__ = ["GM_PEAK_ADEV", "GM_PEAK_TAU", "GM_TO_ALLAN_BI", "channel_avar", "expected_bias_instability",
           "gauss_markov_avar", "sim_channel_params"]
