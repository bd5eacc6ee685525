"""A static recording of the simulated IMU alone (no table motion) and what its noise terms should be.

`simulate_static` runs `bench.sim.imu.SimImu` on a table that never moves (Z up, so
the outputs are Earth rate and gravity plus noise) block by block and returns the six
channels in Allan units: gyro outputs / Kg in deg/h, accelerometer outputs / Ka in ug
(the noise is added on the input side, so this is the noise in input units exactly).
`sim_truth` gives, per channel, the configured terms in the result's units and the
bias instability the flat-region rule should read (`bench.noise.theory`).
"""

from __future__ import annotations

import numpy as np

from bench.model.earth import HANGZHOU_LATITUDE_DEG, Site
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.noise_result import CHANNELS
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.noise.allan import cluster_sizes
from bench.noise.theory import GM_TO_ALLAN_BI, expected_bias_instability, sim_channel_params
from bench.sim.imu import SimImu
from bench.sim.table import SimTable

_BLOCK_S = 2000.0     # simulated seconds per generate() call (bounds the integrator's temporaries)


def counts_to_allan_units(gyro_rate: np.ndarray, acc_rate: np.ndarray, gyro_scale: np.ndarray,
                          acc_scale: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """(n, 6) deg/h and ug from counts/s and the scales (counts/s per rad/s, per m/s^2)."""
    n = len(gyro_rate)
    out = np.empty((n, 6)) if out is None else out
    out[:, :3] = gyro_rate / (np.asarray(gyro_scale) * DEG_PER_HOUR)
    out[:, 3:] = acc_rate / (np.asarray(acc_scale) * MICRO_G)
    return out


def simulate_static(noise: NoiseModel, *, duration_s: float, rate_hz: float, seed: int = 0,
                    imu: ImuCoefficients | None = None, latitude_deg: float = HANGZHOU_LATITUDE_DEG) -> np.ndarray:
    """(n, 6) static outputs in deg/h (gyros) and ug (accelerometers), n = floor(duration_s * rate_hz)."""
    imu = default_sim_imu() if imu is None else imu
    table = SimTable(Site(latitude_deg=latitude_deg))
    sim = SimImu(imu, noise, rate_hz=rate_hz, seed=seed)
    n_total = int(np.floor(duration_s * rate_hz + 1e-9))
    out = np.empty((n_total, 6))
    done = 0
    t = 0.0
    while done < n_total:
        t = min(t + _BLOCK_S, n_total / rate_hz)
        block = sim.generate(table, t)
        n = min(len(block), n_total - done)
        counts_to_allan_units(block.gyro_rate[:n], block.acc_rate[:n], imu.gyro_scale, imu.acc_scale,
                              out=out[done:done + n])
        done += n
    return out


def sim_truth(noise: NoiseModel, imu: ImuCoefficients, n_samples: int, rate_hz: float,
              points_per_octave: int = 1) -> dict:
    """Per channel the configured terms in the result's units and the expected Allan bias instability."""
    tau_s = cluster_sizes(n_samples, points_per_octave) / rate_hz
    params = sim_channel_params(noise, imu)
    truth: dict = {"noise_model": {k: getattr(noise, k) for k in noise.__dataclass_fields__},
                   "gm_to_allan_bi": GM_TO_ALLAN_BI, "channels": {}}
    for name in CHANNELS:
        p = params[name]
        bi = expected_bias_instability(tau_s, p)
        if name.startswith("gyro"):
            terms = {"arw": noise.gyro_arw_deg_rt_h, "rrw": noise.gyro_rrw_dph_rt_h, "bias_instability": bi,
                     "gauss_markov_sigma": noise.gyro_bias_instability_dph, "quantisation": p["q"]}
        else:
            terms = {"vrw": noise.acc_vrw_ug_rt_hz, "rrw": noise.acc_rrw_ug_rt_h, "bias_instability": bi,
                     "gauss_markov_sigma": noise.acc_bias_instability_ug, "quantisation": p["q"]}
        truth["channels"][name] = terms
    return truth


__all__ = ["counts_to_allan_units", "sim_truth", "simulate_static"]
