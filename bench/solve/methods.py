"""Position and rotation methods as general least squares (docs/explanation/solver.md).

Position method, per accelerometer s: `J_s,k = p_s . f_k + q_s` over positions k with
the nominal specific force f_k; `Ka = |p|`, `Ea = p/Ka`, `K0 = q/Ka`. Gyro bias:
`D0_s = mean_k(F_s,k/Kg_s - Eg_s . w_k)` with Kg, Eg from the rotation method.

Rotation method, per gyro s: `int F_s = M_s . (d 2 pi N u_k + E_k) + c_s T_k` over
turns k; `Kg = |M_s|`, `Eg = M_s/Kg` (c_s = Kg D0 is a by-product).

Uncertainties: weighted least squares with the per-step sample noise (pooled over the
dwells of a sensor, see `pooled_sigma`); when the
residual scatter is significantly larger than that noise (chi-square test at 1%) the
covariance is scaled by chi2/dof and a quality flag says so. Without sample noise,
the residual scatter alone sets the scale.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import chdtrc

from bench.errors import InputError
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients
from bench.model.kinematics import attitude
from bench.model.observations import PositionObservation, RotationObservation, turn_axis_in_body
from bench.model.units import DEG

CHI2_ALPHA = 0.01


class SolverError(InputError):
    """The observations cannot determine the coefficients asked for."""


@dataclass
class LinearFit:
    """Per-sensor linear least squares `Y[:, s] = A @ params[s]`."""

    params: np.ndarray        # (S, P)
    cov: np.ndarray           # (S, P, P)
    residuals: np.ndarray     # (K, S)
    normalized: np.ndarray    # (K, S) residual / its 1-sigma (NaN if unknown)
    chi2_per_dof: np.ndarray  # (S,)
    dof: int
    scaled: list[bool]        # per sensor: covariance scaled up by the residual scatter
    weighted: bool
    #: (S, P, P) the covariance from the sample noise alone, never scaled (the budget's Type A part);
    #: without weights, from the residual scatter (then it equals `cov`)
    cov_noise: np.ndarray | None = None
    #: (K, S) the 1-sigma each observation was weighted by (None: unweighted)
    sigma: np.ndarray | None = None


def fit_per_sensor(design: np.ndarray, y: np.ndarray, sigma: np.ndarray | None) -> LinearFit:
    """Weighted (if `sigma` is given and positive) least squares, one sensor per column of y."""
    k, p = design.shape
    dof = k - p
    weights = sigma if sigma is not None and np.all(np.isfinite(sigma)) and np.all(sigma > 0) else None
    use_weights = weights is not None
    params, covs, covs0, resid, normd, chi2n, scaled = [], [], [], [], [], [], []
    for s in range(y.shape[1]):
        w = 1.0 / weights[:, s] if weights is not None else np.ones(k)
        aw = design * w[:, None]
        sol, *_ = np.linalg.lstsq(aw, y[:, s] * w, rcond=None)
        r = y[:, s] - design @ sol
        chi2 = float(np.sum((r * w) ** 2))
        try:
            cov0 = np.linalg.inv(aw.T @ aw)
        except np.linalg.LinAlgError as exc:
            raise SolverError(f"the observations do not determine the {p} parameters of sensor {s} "
                              f"(singular normal matrix)") from exc
        red = chi2 / dof if dof > 0 else math.nan
        if use_weights:
            scale_up = dof > 0 and red > 1.0 and chdtrc(dof, chi2) < CHI2_ALPHA
            factor = red if scale_up else 1.0
        else:
            scale_up = False
            factor = red
        params.append(sol)
        covs.append(cov0 * factor)
        covs0.append(cov0 if use_weights else cov0 * factor)
        resid.append(r)
        normd.append(r * w / math.sqrt(factor) if math.isfinite(factor) and factor > 0 else np.full(k, math.nan))
        chi2n.append(red)
        scaled.append(bool(scale_up))
    return LinearFit(np.array(params), np.array(covs), np.array(resid).T, np.array(normd).T,
                     np.array(chi2n), dof, scaled, bool(use_weights), np.array(covs0),
                     np.asarray(weights, dtype=float) if use_weights else None)


def _require_rank(design: np.ndarray, what: str) -> None:
    if not np.all(np.isfinite(design)):   # a log whose table states hold null angles: no SVD converges on NaN
        raise SolverError(f"{what}: the steps' table angles or rates are not all finite numbers")
    rank = np.linalg.matrix_rank(design, tol=1e-9 * np.abs(design).max())
    if rank < design.shape[1]:
        raise SolverError(f"{what}: the steps determine only {rank} of {design.shape[1]} unknowns per sensor "
                          f"(need steps along all three body axes in both senses)")


def scale_axes_bias(params: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From fitted (..., 4) = (p, q): scale |p|, unit axes p/|p|, bias q/|p| (input units)."""
    p, q = params[..., :3], params[..., 3]
    scale = np.linalg.norm(p, axis=-1)
    return scale, p / scale[..., None], q / scale


def scale_axes_bias_jacobian(params: np.ndarray) -> np.ndarray:
    """d(scale, axes[3], bias)/d(p, q) for one sensor: (5, 4)."""
    p, q = params[:3], params[3]
    m = float(np.linalg.norm(p))
    u = p / m
    jac = np.zeros((5, 4))
    jac[0, :3] = u
    jac[1:4, :3] = (np.eye(3) - np.outer(u, u)) / m
    jac[4, :3] = -q * u / m ** 2
    jac[4, 3] = 1.0 / m
    return jac


@dataclass
class SensorTriad:
    """Scale, axes and bias of three sensors (SI) with their covariance (per sensor, 5x5)."""

    scale: np.ndarray
    axes: np.ndarray
    bias: np.ndarray
    cov: np.ndarray   # (3, 5, 5) over (scale, axes X Y Z, bias)
    fit: LinearFit

    def cov_noise_sensor(self, s: int) -> np.ndarray:
        """(5, 5) covariance of sensor s's (scale, axes, bias) from the sample noise alone (never scaled)."""
        cov = self.fit.cov_noise if self.fit.cov_noise is not None else self.fit.cov
        jac = scale_axes_bias_jacobian(self.fit.params[s])
        return jac @ cov[s] @ jac.T

    @classmethod
    def from_fit(cls, fit: LinearFit) -> "SensorTriad":
        scale, axes, bias = scale_axes_bias(fit.params)
        cov = np.array([j @ c @ j.T for j, c in
                        zip((scale_axes_bias_jacobian(p) for p in fit.params), fit.cov)])
        return cls(scale, axes, bias, cov, fit)


def nominal_position_inputs(angles_deg: np.ndarray, site: Site, mounting=None) -> tuple[np.ndarray, np.ndarray]:
    """Nominal (ideal table) specific force and Earth rate in body axes at each position."""
    c_tb = attitude(np.asarray(angles_deg, dtype=float) * DEG, mounting=mounting)
    return c_tb @ site.specific_force_enu, c_tb @ site.earth_rate_enu


def position_design(angles_deg: np.ndarray, site: Site, mounting=None) -> np.ndarray:
    """Design matrix `[f_k, 1]` (K, 4) of the position method."""
    f, _ = nominal_position_inputs(angles_deg, site, mounting)
    return np.column_stack([f, np.ones(len(f))])


def rotation_design(observations: list[RotationObservation], site: Site, mounting=None) -> np.ndarray:
    """Design matrix `[d 2 pi N u_k + E_k, T_k]` (K, 4) of the rotation method."""
    rows = []
    for obs in observations:
        u = turn_axis_in_body(obs.start_deg, obs.frame_index, mounting=mounting)
        earth = obs.earth_integral_rad
        if earth is None:
            w_b = attitude(np.asarray(obs.start_deg) * DEG, mounting=mounting) @ site.earth_rate_enu
            earth = obs.duration_s * float(u @ w_b) * u
        rows.append(np.concatenate([obs.sign * 2.0 * math.pi * obs.revolutions * u + earth, [obs.duration_s]]))
    return np.array(rows)


def pooled_sigma(sem: np.ndarray, durations_s) -> np.ndarray:
    """(K, S) 1-sigma of each dwell mean from the noise density pooled over all dwells of a sensor,
    `sqrt(mean_k(sem_k^2 T_k) / T_k)`: every dwell of one length gets the same weight.

    Weights from each dwell's own standard error (a noisy estimate, and for quantised
    outputs one that depends on the signal itself) make the weights differ at random and
    break the symmetry by which an optimal schedule cancels the table's pointing error to
    first order; the pooled density keeps it.
    """
    t = np.asarray(durations_s, dtype=float)[:, None]
    density2 = np.mean(np.asarray(sem, dtype=float) ** 2 * t, axis=0)
    return np.sqrt(density2 / t)


@dataclass
class GyroBias:
    value: np.ndarray   # (3,) rad/s
    sigma: np.ndarray   # (3,) rad/s
    residuals: np.ndarray   # (K, 3) rad/s
    normalized: np.ndarray  # (K, 3)
    chi2_per_dof: np.ndarray
    scaled: list[bool]
    #: (3,) rad/s: the sample-noise part of sigma (positions and the rotation fit's M), never scaled
    sigma_noise: np.ndarray | None = None
    #: (3, 3): d(D0_s)/d(M_s), to carry other errors of the rotation fit into the bias
    dd_dm: np.ndarray | None = None


def gyro_bias_from_positions(obs: list[PositionObservation], site: Site, gyro: SensorTriad | ImuCoefficients,
                             mounting=None) -> GyroBias:
    """`D0_s = mean_k(F_s,k/Kg_s - Eg_s . w_k)`, its sigma including the Kg/Eg uncertainty."""
    angles = np.array([o.angles_deg for o in obs])
    _, w_nominal = nominal_position_inputs(angles, site, mounting)
    f_out = np.array([o.gyro_mean for o in obs])
    sem = [o.standard_error("gyro") for o in obs]
    have_sem = all(s is not None for s in sem)
    if isinstance(gyro, ImuCoefficients):
        scale, axes, m_cov = gyro.gyro_scale, gyro.gyro_axes, np.zeros((3, 3, 3))
    else:
        # The rotation fit's first three parameters are M_s = Kg_s Eg_s itself.
        scale, axes, m_cov = gyro.scale, gyro.axes, gyro.fit.cov[:, :3, :3]
    z = f_out / scale - w_nominal @ axes.T
    sigma = pooled_sigma(np.array(sem), [o.duration_s for o in obs]) / scale if have_sem else None
    fit = fit_per_sensor(np.ones((len(obs), 1)), z, sigma)
    value = fit.params[:, 0]
    var = fit.cov[:, 0, 0].copy()
    var_noise = (fit.cov_noise if fit.cov_noise is not None else fit.cov)[:, 0, 0].copy()
    m_cov_noise = m_cov if isinstance(gyro, ImuCoefficients) or gyro.fit.cov_noise is None \
        else gyro.fit.cov_noise[:, :3, :3]
    f_mean, w_mean = f_out.mean(axis=0), w_nominal.mean(axis=0)
    jac = np.zeros((3, 3))
    for s in range(3):
        # D0 = mean(F)/|M| - (M/|M|).mean(w): propagate the covariance of M_s.
        m, g = scale[s], axes[s]
        dd_dm = -f_mean[s] * g / m ** 2 - (w_mean - g * (g @ w_mean)) / m
        jac[s] = dd_dm
        var[s] += float(dd_dm @ m_cov[s] @ dd_dm)
        var_noise[s] += float(dd_dm @ m_cov_noise[s] @ dd_dm)
    return GyroBias(value, np.sqrt(var), fit.residuals, fit.normalized, fit.chi2_per_dof, fit.scaled,
                    np.sqrt(var_noise) if have_sem else None, jac)


def solve_accelerometers(obs: list[PositionObservation], site: Site, mounting=None) -> SensorTriad:
    """Position method for the accelerometers."""
    if len(obs) < 4:
        raise SolverError(f"position method needs at least 4 positions, got {len(obs)}")
    design = position_design(np.array([o.angles_deg for o in obs]), site, mounting)
    _require_rank(design, "position schedule")
    sem = [o.standard_error("acc") for o in obs]
    sigma = pooled_sigma(np.array(sem), [o.duration_s for o in obs]) if all(s is not None for s in sem) else None
    return SensorTriad.from_fit(fit_per_sensor(design, np.array([o.acc_mean for o in obs]), sigma))


def solve_gyros(obs: list[RotationObservation], site: Site, mounting=None,
                noise_density: np.ndarray | None = None) -> SensorTriad:
    """Rotation method. `noise_density` (counts/s * sqrt(s), per gyro) sets the integral's
    white-noise sigma, density * sqrt(T), when the observations carry none."""
    if len(obs) < 4:
        raise SolverError(f"rotation method needs at least 4 turns, got {len(obs)}")
    design = rotation_design(obs, site, mounting)
    _require_rank(design, "rotation schedule")
    y = np.array([o.gyro_integral for o in obs])
    if all(o.gyro_integral_sigma is not None for o in obs):
        sigma = np.array([o.gyro_integral_sigma for o in obs])
    elif noise_density is not None:
        sigma = np.array([noise_density * math.sqrt(o.duration_s) for o in obs])
    else:
        sigma = None
    return SensorTriad.from_fit(fit_per_sensor(design, y, sigma))
