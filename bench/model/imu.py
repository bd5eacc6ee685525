"""IMU model (docs/explanation/model.md#imu-model, paper eq. 1) and its canonical coefficient names.

gyro s:  F_s = Kg_s * (Eg_s . w_b + D0_s)      accel s:  J_s = Ka_s * (Ea_s . f_b + K0_s)

Internally SI: Kg in counts/s per rad/s, D0 in rad/s, Ka in counts/s per m/s^2,
K0 in m/s^2. `Eg`/`Ea` rows are unit vectors (direction cosines of each sensor's
sensitive axis in body X, Y, Z).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES, canonical_names
from bench.model.units import DEG, DEG_PER_HOUR, G0


def _unit_rows(m: np.ndarray) -> np.ndarray:
    return m / np.linalg.norm(m, axis=-1, keepdims=True)


@dataclass
class ImuCoefficients:
    """The 30 model coefficients of one IMU (SI internally)."""

    gyro_scale: np.ndarray          # (3,) counts/s per rad/s
    gyro_bias: np.ndarray           # (3,) rad/s
    gyro_axes: np.ndarray           # (3, 3) unit rows
    acc_scale: np.ndarray           # (3,) counts/s per m/s^2
    acc_bias: np.ndarray            # (3,) m/s^2
    acc_axes: np.ndarray            # (3, 3) unit rows

    def __post_init__(self) -> None:
        for name in ("gyro_scale", "gyro_bias", "acc_scale", "acc_bias"):
            setattr(self, name, np.asarray(getattr(self, name), dtype=float).reshape(3))
        for name in ("gyro_axes", "acc_axes"):
            m = np.asarray(getattr(self, name), dtype=float).reshape(3, 3)
            setattr(self, name, m)

    # -- the model ---------------------------------------------------------
    @property
    def gyro_matrix(self) -> np.ndarray:
        """`M = diag(Kg) Eg`: counts/s per rad/s of body rate."""
        return self.gyro_scale[:, None] * self.gyro_axes

    @property
    def acc_matrix(self) -> np.ndarray:
        return self.acc_scale[:, None] * self.acc_axes

    def gyro_output(self, body_rate: np.ndarray) -> np.ndarray:
        """Gyro outputs (counts/s) for body rates (..., 3) in rad/s."""
        return np.asarray(body_rate) @ self.gyro_matrix.T + self.gyro_scale * self.gyro_bias

    def acc_output(self, specific_force: np.ndarray) -> np.ndarray:
        """Accelerometer outputs (counts/s) for specific forces (..., 3) in m/s^2."""
        return np.asarray(specific_force) @ self.acc_matrix.T + self.acc_scale * self.acc_bias

    # -- canonical names ---------------------------------------------------
    def to_canonical(self) -> dict[str, float]:
        """Values in display units keyed by canonical name (deg/h, g, counts/s per deg/s or per g)."""
        out: dict[str, float] = {}
        groups = (("Kg", "D0", "Eg", self.gyro_scale, self.gyro_bias, self.gyro_axes),
                  ("Ka", "K0", "Ea", self.acc_scale, self.acc_bias, self.acc_axes))
        for scale, bias, axes, sv, bv, av in groups:
            for i, s in enumerate(SENSOR_AXES):
                out[f"{scale}_{s}"] = float(sv[i]) / RESULT_UNITS[scale][1]
                out[f"{bias}_{s}"] = float(bv[i]) / RESULT_UNITS[bias][1]
                for j, a in enumerate(BODY_AXES):
                    out[f"{axes}_{a}{s}"] = float(av[i, j])
        return {name: out[name] for name in canonical_names()}

    @classmethod
    def from_canonical(cls, values: dict[str, float]) -> "ImuCoefficients":
        """Inverse of `to_canonical`; raises KeyError naming a missing coefficient."""
        def vec(prefix: str) -> np.ndarray:
            return np.array([values[f"{prefix}_{s}"] for s in SENSOR_AXES]) * RESULT_UNITS[prefix][1]

        def mat(prefix: str) -> np.ndarray:
            return np.array([[values[f"{prefix}_{a}{s}"] for a in BODY_AXES] for s in SENSOR_AXES])

        return cls(vec("Kg"), vec("D0"), mat("Eg"), vec("Ka"), vec("K0"), mat("Ea"))

    @classmethod
    def ideal(cls, gyro_scale_per_dps: float = 36000.0, acc_scale_per_g: float = 40000.0) -> "ImuCoefficients":
        """A perfect IMU: orthogonal axes, no bias."""
        return cls(np.full(3, gyro_scale_per_dps / DEG), np.zeros(3), np.eye(3),
                   np.full(3, acc_scale_per_g / G0), np.zeros(3), np.eye(3))


def default_sim_imu() -> ImuCoefficients:
    """The simulated navigation-grade FOG IMU used by `--sim` and the Monte-Carlo tables.

    Scale factors near 0.1 arcsec/pulse (gyros) and 40000 pulses/s per g
    (accelerometers), biases of realistic size, off-diagonal direction cosines of
    4e-4 to 9e-4 rad.
    """
    gyro_axes = _unit_rows(np.array([
        [1.0, 6.2e-4, -4.5e-4],
        [-7.1e-4, 1.0, 8.3e-4],
        [5.4e-4, -9.0e-4, 1.0],
    ]))
    acc_axes = _unit_rows(np.array([
        [1.0, -5.3e-4, 7.7e-4],
        [4.1e-4, 1.0, -6.6e-4],
        [-8.8e-4, 4.9e-4, 1.0],
    ]))
    return ImuCoefficients(
        gyro_scale=np.array([36012.5, 35987.2, 36021.9]) / DEG,
        gyro_bias=np.array([0.052, -0.031, 0.078]) * DEG_PER_HOUR,
        gyro_axes=gyro_axes,
        acc_scale=np.array([40021.0, 39978.5, 40009.3]) / G0,
        acc_bias=np.array([1.2e-4, -0.8e-4, 2.1e-4]) * G0,
        acc_axes=acc_axes,
    )


def default_sim_si_imu() -> ImuCoefficients:
    """The simulated MEMS IMU whose outputs are calibrated SI values (rad/s, m/s^2): what an IMU sending
    physical units (the sbg-ecan layout) is, seen by the model: scale factors near 1 (rad/s per rad/s,
    m/s^2 per m/s^2: display pi/180 counts/s per deg/s and g0 counts/s per g), the residual errors of a
    factory calibration (scale 1e-4 to 4e-4, misalignments 5e-4 to 1.2e-3 rad, biases of tens of deg/h
    and a few mg)."""
    gyro_axes = _unit_rows(np.array([
        [1.0, 8.0e-4, -6.0e-4],
        [-9.0e-4, 1.0, 1.1e-3],
        [7.0e-4, -1.2e-3, 1.0],
    ]))
    acc_axes = _unit_rows(np.array([
        [1.0, -7.0e-4, 9.0e-4],
        [5.0e-4, 1.0, -8.0e-4],
        [-1.0e-3, 6.0e-4, 1.0],
    ]))
    return ImuCoefficients(
        gyro_scale=np.array([1.00025, 0.99968, 1.00012]),
        gyro_bias=np.array([25.0, -18.0, 32.0]) * DEG_PER_HOUR,
        gyro_axes=gyro_axes,
        acc_scale=np.array([1.00031, 0.99979, 1.00042]),
        acc_bias=np.array([2.0e-3, -1.5e-3, 2.5e-3]) * G0,
        acc_axes=acc_axes,
    )


@dataclass(frozen=True)
class NoiseModel:
    """Sensor noise of the simulated IMU (display units; zero disables a term).

    Bias instability is a first-order Gauss-Markov process with the given 1-sigma
    and correlation time (its Allan deviation peaks at 0.617 sigma at tau = 1.89
    correlation times, which IEEE 952's flat-region rule B = min ADEV / 0.664 reads as
    0.929 sigma: see `bench.noise.theory`). Rate random walk: a bias that random-walks
    from 0 (Allan slope +1/2), off by default.
    """

    gyro_arw_deg_rt_h: float = 0.002            # angle random walk, deg/sqrt(h)
    gyro_bias_instability_dph: float = 0.003    # deg/h
    acc_vrw_ug_rt_hz: float = 10.0              # velocity random walk as white-noise density, ug/sqrt(Hz)
    acc_bias_instability_ug: float = 2.0        # ug
    correlation_time_s: float = 300.0
    quantise: bool = True                       # integer counts per sample, remainder carried
    gyro_rrw_dph_rt_h: float = 0.0              # rate random walk (a bias that random-walks), deg/h/sqrt(h)
    acc_rrw_ug_rt_h: float = 0.0                # accelerometer bias random walk, ug/sqrt(h)

    @classmethod
    def off(cls) -> "NoiseModel":
        return cls(0.0, 0.0, 0.0, 0.0, 300.0, False)

    @classmethod
    def mems(cls) -> "NoiseModel":
        """Noise of the simulated MEMS IMU (`default_sim_si_imu`): data-sheet levels of an industrial MEMS
        unit; no integer quantisation (an IMU sending physical units is quantised by its output format)."""
        return cls(gyro_arw_deg_rt_h=0.15, gyro_bias_instability_dph=7.0, acc_vrw_ug_rt_hz=60.0,
                   acc_bias_instability_ug=15.0, correlation_time_s=300.0, quantise=False)

    @property
    def enabled(self) -> bool:
        return bool(self.gyro_arw_deg_rt_h or self.gyro_bias_instability_dph or self.acc_vrw_ug_rt_hz
                    or self.acc_bias_instability_ug or self.quantise or self.gyro_rrw_dph_rt_h
                    or self.acc_rrw_ug_rt_h)


__all__ = ["ImuCoefficients", "NoiseModel", "default_sim_imu", "default_sim_si_imu"]
