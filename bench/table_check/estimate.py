"""Turntable check (paper section 5.1): the table's pointing error from the horizontal accelerometers.

With the middle frame at 0 the body X and Y axes are horizontal; on an ideal table the
x and y accelerometers read the same at every (outer, inner) position. The nine
black-box angles (rows outer base `C_t^o0`, middle `C_o^m0`, inner `C_m^i0`; columns
alpha about y, beta about x, gamma about z, see `bench.model.kinematics`) make them vary.

Linearising the exact model (`bench.model.kinematics.attitude`) over the positions and
projecting out one constant offset per accelerometer (bias plus vertical misalignment)
leaves exactly four observable combinations (`observability` verifies it by SVD):

- `level_alpha` = alpha_o, `level_beta` = beta_o: the tilt of the outer axis from the
  local vertical (how level the table stands);
- `inner_alpha` = alpha_m + alpha_i, `inner_beta` = beta_m + beta_i: the tilt of the
  inner axis against the outer axis at middle 0, where the middle and inner black boxes
  act together (alpha: the middle frame's zero offset and the inner axis tilted about
  the middle axis; beta: the non-perpendicularity of middle-to-outer plus inner-to-middle).

The gammas (zero offsets about the frames' own axes) enter only at second order.

The estimate fits an exact four-parameter model: at middle 0,
`C_t^b = C_i(th_i) Q C_o(th_o) C_t^o0` with `Q = C_m^i0 C_o^m0`; writing `Q = T Rz(psi)`
(T a tilt `R_y(a) R_x(b)`) the twist commutes with `C_o`, so the horizontal specific
force is `C_i(th_i) T C_o(th_o) u` exactly, with `u = Rz(psi) C_t^o0 e_z`. The four
combinations are defined exactly as (a, b) of T and the tilt angles of u; to first
order they equal the linear combinations above (`true_combinations` projects a full
black box). All angles here are radians; `*_arcsec` helpers are for display.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular

from bench.errors import InputError
from bench.model.kinematics import attitude, black_box_matrix, rot_z
from bench.model.units import ARCSEC, DEG
from bench.solve.budget import gm_mean_kernel

ANGLE_NAMES = ("alpha_o", "beta_o", "gamma_o", "alpha_m", "beta_m", "gamma_m", "alpha_i", "beta_i", "gamma_i")


class TableCheckError(InputError):
    """Positions or data from which the table check cannot be computed."""


@dataclass(frozen=True)
class Combination:
    """One observable combination of the nine black-box angles (first-order coefficients)."""

    key: str
    title: str
    description: str
    coefficients: dict[str, float]

    @property
    def formula(self) -> str:
        """e.g. 'alpha_m + alpha_i'."""
        terms = []
        for name, c in self.coefficients.items():
            mag = "" if abs(abs(c) - 1.0) < 1e-9 else f"{abs(c):.6g}*"
            sign = "-" if c < 0 else "+"
            terms.append((sign, mag + name))
        text = " ".join(f"{s} {t}" for s, t in terms)
        return text[2:] if text.startswith("+ ") else "-" + text[2:]

    def to_dict(self) -> dict:
        return {"key": self.key, "title": self.title, "description": self.description, "formula": self.formula,
                "coefficients": dict(self.coefficients)}


COMBINATIONS = (
    Combination("level_alpha", "outer axis tilt (levelness), alpha",
                "tilt of the outer axis from the local vertical about the base's y axis: how level the table stands",
                {"alpha_o": 1.0}),
    Combination("level_beta", "outer axis tilt (levelness), beta",
                "tilt of the outer axis from the local vertical about the base's x axis: how level the table stands",
                {"beta_o": 1.0}),
    Combination("inner_alpha", "inner axis tilt at middle 0, alpha",
                "inner axis tilted against the outer axis about the middle axis (y): the middle frame's zero offset "
                "and the inner box's alpha act together", {"alpha_m": 1.0, "alpha_i": 1.0}),
    Combination("inner_beta", "inner axis tilt at middle 0, beta",
                "inner axis tilted against the outer axis about x: non-perpendicularity of middle-to-outer and of "
                "inner-to-middle act together", {"beta_m": 1.0, "beta_i": 1.0}),
)
COMBINATION_KEYS = tuple(c.key for c in COMBINATIONS)


def combination_matrix() -> np.ndarray:
    """(4, 9) first-order coefficients of the combinations on the nine angles (ANGLE_NAMES order)."""
    out = np.zeros((len(COMBINATIONS), len(ANGLE_NAMES)))
    for i, c in enumerate(COMBINATIONS):
        for name, coef in c.coefficients.items():
            out[i, ANGLE_NAMES.index(name)] = coef
    return out


# -- positions ----------------------------------------------------------------------------

def check_positions(angles_deg) -> np.ndarray:
    """The positions as a (K, 3) array; TableCheckError unless every middle angle is 0 and outer/inner vary enough."""
    try:
        a = np.asarray(angles_deg, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TableCheckError(f"positions must be (outer, middle, inner) angles in deg: {exc}") from exc
    if a.ndim != 2 or a.shape[1] != 3 or not len(a):
        raise TableCheckError(f"positions must be a (K, 3) array of angles in deg, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise TableCheckError("positions hold non-finite angles")
    middle = (a[:, 1] + 180.0) % 360.0 - 180.0
    off = np.flatnonzero(np.abs(middle) > 1e-6)
    if len(off):
        raise TableCheckError(f"{len(off)} of {len(a)} positions have the middle frame off 0 (first: "
                              f"{tuple(float(x) for x in a[off[0]])}); the table check needs middle 0 everywhere")
    return a


def horizontal_force(angles_deg, black_box_rad=None) -> np.ndarray:
    """Exact horizontal specific force (body X, Y) in units of local g, (K, 2), from `attitude`."""
    c_tb = attitude(np.asarray(angles_deg, dtype=float) * DEG, black_box_rad)
    return c_tb[..., :2, 2]


def black_box_jacobian(angles_deg, step_rad: float = 1e-7) -> np.ndarray:
    """d(horizontal force / g)/d(black-box angle) at the ideal table, (2K, 9), rows x0, y0, x1, y1, ..."""
    cols = []
    for k in range(9):
        d = np.zeros(9)
        d[k] = step_rad
        plus = horizontal_force(angles_deg, d.reshape(3, 3)).ravel()
        minus = horizontal_force(angles_deg, -d.reshape(3, 3)).ravel()
        cols.append((plus - minus) / (2.0 * step_rad))
    return np.stack(cols, axis=1)


def offset_columns(count: int) -> np.ndarray:
    """(2K, 2) nuisance columns: a constant offset of the x and of the y accelerometer."""
    n = np.zeros((2 * count, 2))
    n[0::2, 0] = 1.0
    n[1::2, 1] = 1.0
    return n


@dataclass(frozen=True)
class Observability:
    """What the positions can see of the nine angles, to first order, after removing the offsets."""

    singular_values: np.ndarray     # (9,) of the offset-projected Jacobian, descending
    rank: int
    row_space: np.ndarray           # (rank, 9) reduced row-echelon basis of the observable combinations
    matches_named: bool             # the row space is exactly that of COMBINATIONS
    combinations: tuple[Combination, ...]

    def to_dict(self) -> dict:
        return {"singular_values": [float(s) for s in self.singular_values], "rank": self.rank,
                "matches_named": self.matches_named, "combinations": [c.to_dict() for c in self.combinations]}


def _rref(m: np.ndarray, tol: float) -> np.ndarray:
    m = m.copy()
    rows, cols = m.shape
    r = 0
    for c in range(cols):
        if r == rows:
            break
        p = r + int(np.argmax(np.abs(m[r:, c])))
        if abs(m[p, c]) < tol:
            continue
        m[[r, p]] = m[[p, r]]
        m[r] /= m[r, c]
        for i in range(rows):
            if i != r:
                m[i] -= m[i, c] * m[r]
        r += 1
    m[np.abs(m) < tol] = 0.0
    return m[:r]


def observability(angles_deg, rel_tol: float = 1e-8) -> Observability:
    """SVD of the Jacobian with the offsets projected out: rank, singular values, the combinations it sees."""
    a = check_positions(angles_deg)
    jac = black_box_jacobian(a)
    n = offset_columns(len(a))
    projected = jac - n @ np.linalg.lstsq(n, jac, rcond=None)[0]
    _, s, vt = np.linalg.svd(projected)
    rank = int(np.sum(s > rel_tol * max(s[0], 1e-300)))
    basis = _rref(vt[:rank], 1e-6)
    named = combination_matrix()
    matches = basis.shape == named.shape and np.allclose(basis, named, atol=1e-6)
    combos: tuple[Combination, ...]
    if matches:
        combos = COMBINATIONS
    else:
        combos = tuple(Combination(f"combination_{i + 1}", f"combination {i + 1}", "observable combination (SVD)",
                                   {ANGLE_NAMES[j]: float(row[j]) for j in np.flatnonzero(row)})
                       for i, row in enumerate(basis))
    return Observability(s, rank, basis, bool(matches), combos)


# -- the exact four-parameter model ---------------------------------------------------------

def _tilt_angles(v: np.ndarray) -> tuple[float, float]:
    """(alpha, beta) of `R_y(alpha) R_x(beta)` whose third column is the unit vector v = (-sa cb, sb, ca cb)."""
    v = v / np.linalg.norm(v)
    return math.atan2(-v[0], v[2]), math.asin(max(-1.0, min(1.0, v[1])))


def true_combinations(black_box_rad) -> np.ndarray:
    """The four combinations (rad, COMBINATION_KEYS order) of a full 3x3 black box, exactly.

    To first order this is `combination_matrix() @ black_box.ravel()`.
    """
    bb = np.asarray(black_box_rad, dtype=float).reshape(3, 3)
    mats = black_box_matrix(bb)
    c_to0, c_om0, c_mi0 = mats[0], mats[1], mats[2]
    q = c_mi0 @ c_om0
    a, b = _tilt_angles(q[:, 2])
    twist = black_box_matrix(np.array([a, b, 0.0])).T @ q    # Rz(psi), exactly a rotation about z
    u = twist @ c_to0[:, 2]
    level_a, level_b = _tilt_angles(u)
    return np.array([level_a, level_b, a, b])


def model_horizontal(combinations_rad, angles_deg) -> np.ndarray:
    """Horizontal specific force / g (K, 2) of the exact model for the four combinations (rad)."""
    p = np.asarray(combinations_rad, dtype=float)
    a = np.asarray(angles_deg, dtype=float) * DEG
    u = black_box_matrix(np.array([p[0], p[1], 0.0]))[:, 2]
    tilt = black_box_matrix(np.array([p[2], p[3], 0.0]))
    v = rot_z(a[:, 2]) @ tilt @ (rot_z(a[:, 0]) @ u)[..., None]
    return v[:, :2, 0]


# -- estimation -------------------------------------------------------------------------------

@dataclass
class TableCheckEstimate:
    """Weighted least-squares estimate of the four combinations and the two accelerometer offsets."""

    angles_deg: np.ndarray          # (K, 3)
    horizontal_g: np.ndarray        # (K, 2) measured x, y in units of local g
    sigma_g: np.ndarray             # (K, 2) the 1-sigma used to weight
    combinations: tuple[Combination, ...]
    values_rad: np.ndarray          # (4,)
    sigma_rad: np.ndarray           # (4,) 1-sigma: noise (scaled by sqrt(reduced chi2) when > 1) and conversion
    covariance_rad2: np.ndarray     # (4, 4) of the same
    offsets_g: np.ndarray           # (2,) x, y: bias + vertical misalignment (+ unobservable terms)
    offsets_sigma_g: np.ndarray     # (2,)
    residual_g: np.ndarray          # (K, 2)
    chi2: float
    dof: int
    iterations: int
    weighted: bool                  # False: no per-position sigmas, the residual scatter sets them
    observability: Observability | None = None
    notes: list[str] = field(default_factory=list)
    sigma_noise_rad: np.ndarray | None = None       # (4,) the noise part of sigma_rad
    sigma_conversion_rad: np.ndarray | None = None  # (4,) the accelerometer-conversion part
    relative_scale_uncertainty: float = 0.0

    @property
    def reduced_chi2(self) -> float:
        return self.chi2 / self.dof if self.dof > 0 else math.nan

    @property
    def sigma_scale(self) -> float:
        """The factor the formal sigmas were multiplied by (>= 1 when weighted)."""
        if not self.weighted:
            return math.sqrt(self.reduced_chi2)
        return math.sqrt(max(1.0, self.reduced_chi2))

    @property
    def residual_rms_g(self) -> float:
        return float(np.sqrt(np.mean(self.residual_g ** 2)))

    @property
    def values_arcsec(self) -> np.ndarray:
        return self.values_rad / ARCSEC

    @property
    def sigma_arcsec(self) -> np.ndarray:
        return self.sigma_rad / ARCSEC

    def compare(self, truth_rad) -> list[dict]:
        """Per combination: estimate, sigma, truth, difference, z = difference/sigma, within 3 sigma."""
        truth = np.asarray(truth_rad, dtype=float)
        rows = []
        for c, v, s, t in zip(self.combinations, self.values_arcsec, self.sigma_arcsec, truth / ARCSEC):
            z = (v - t) / s if s > 0 else math.inf
            rows.append({"key": c.key, "estimate_arcsec": float(v), "sigma_arcsec": float(s), "truth_arcsec": float(t),
                         "difference_arcsec": float(v - t), "z": float(z), "within_3_sigma": bool(abs(z) <= 3.0)})
        return rows

    def to_dict(self) -> dict:
        """JSON-ready summary (arcsec, g)."""
        return {
            "combinations": [{**c.to_dict(), "value_arcsec": float(v), "sigma_arcsec": float(s)}
                             for c, v, s in zip(self.combinations, self.values_arcsec, self.sigma_arcsec)],
            "sigma_noise_arcsec": _arcsec_list(self.sigma_noise_rad),
            "sigma_conversion_arcsec": _arcsec_list(self.sigma_conversion_rad),
            "relative_scale_uncertainty": self.relative_scale_uncertainty,
            "correlation": _correlation(self.covariance_rad2).tolist(),
            "offsets_g": {"x": float(self.offsets_g[0]), "y": float(self.offsets_g[1])},
            "offsets_sigma_g": {"x": float(self.offsets_sigma_g[0]), "y": float(self.offsets_sigma_g[1])},
            "residual_rms_g": self.residual_rms_g,
            "residual_rms_arcsec": self.residual_rms_g / ARCSEC,
            "chi2": self.chi2, "dof": self.dof, "reduced_chi2": self.reduced_chi2,
            "sigma_scale": self.sigma_scale, "weighted": self.weighted, "positions": int(len(self.angles_deg)),
            "iterations": self.iterations, "notes": list(self.notes),
            "observability": self.observability.to_dict() if self.observability is not None else None,
        }


def _arcsec_list(x) -> list[float] | None:
    return None if x is None else [float(v) for v in np.asarray(x) / ARCSEC]


def _correlation(cov: np.ndarray) -> np.ndarray:
    d = np.sqrt(np.diag(cov))
    with np.errstate(invalid="ignore", divide="ignore"):
        out = cov / np.outer(d, d)
    return np.nan_to_num(out)


def _design(p: np.ndarray, angles_deg: np.ndarray, step_rad: float = 1e-6) -> np.ndarray:
    """(2K, 6) derivative of the exact model (4 angles, then x and y offsets)."""
    cols = []
    for k in range(4):
        d = np.zeros(4)
        d[k] = step_rad
        cols.append((model_horizontal(p + d, angles_deg) - model_horizontal(p - d, angles_deg)).ravel()
                    / (2.0 * step_rad))
    return np.concatenate([np.stack(cols, axis=1), offset_columns(len(angles_deg))], axis=1)


def _whitener(sigma: np.ndarray, drift_g: float, start_s, duration_s, correlation_time_s: float):
    """A function M -> C^(-1/2) M for the stacked (x0, y0, x1, ...) means: C = diag(sigma^2) plus
    the accelerometer bias drift, a Gauss-Markov bias of 1-sigma `drift_g` per axis that two
    dwells share by their distance in time (`bench.solve.budget.gm_mean_kernel`)."""
    w = 1.0 / sigma.ravel()
    if not drift_g > 0:
        return lambda m: m * (w[:, None] if m.ndim == 2 else w)
    k = len(sigma)
    starts = np.asarray(start_s if start_s is not None else np.zeros(k), dtype=float)
    durations = np.asarray(duration_s if duration_s is not None else np.ones(k), dtype=float)
    if start_s is None:     # unknown: end to end in order
        starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    kernel = gm_mean_kernel(starts, durations, correlation_time_s)
    cov = np.diag(sigma.ravel() ** 2) + drift_g ** 2 * np.kron(kernel, np.eye(2))
    chol = np.linalg.cholesky(cov)
    return lambda m: solve_triangular(chol, m, lower=True)


def estimate(angles_deg, horizontal_g, sigma_g=None, *, relative_scale_uncertainty: float = 0.0,
             max_iterations: int = 20, with_observability: bool = True, drift_g: float = 0.0,
             start_s=None, duration_s=None, correlation_time_s: float = 300.0) -> TableCheckEstimate:
    """Fit the four combinations and the x, y offsets to horizontal accelerometer means (units of local g).

    `sigma_g` (K, 2) are the 1-sigma of the means (None: equal weights, the residual
    scatter sets the uncertainty). Gauss-Newton on the exact model from zero; the
    formal covariance is scaled by the reduced chi-square when it exceeds 1.

    `relative_scale_uncertainty` (eps) is how well counts became g in the x/y plane: a
    common scale error of x and y scales both tilt vectors and an in-plane misalignment
    turns them (a scale mismatch between x and y only adds residuals). Each component of
    a tilt vector t gets eps * |t| added in quadrature to its noise sigma.

    `drift_g` (units of g, 1-sigma) models the accelerometers' bias drift over the check
    as a Gauss-Markov bias with `correlation_time_s`, correlating dwells by their
    `start_s` and `duration_s` (end to end in order when not given): generalised least
    squares with that covariance, so that short dwells, where the drift is not small
    against the sample noise, get right sigmas too. Ignored without `sigma_g`.
    """
    a = check_positions(angles_deg)
    y = np.asarray(horizontal_g, dtype=float)
    if y.shape != (len(a), 2) or not np.all(np.isfinite(y)):
        raise TableCheckError(f"horizontal accelerometer means must be finite, shape ({len(a)}, 2), got {y.shape}")
    weighted = sigma_g is not None
    sigma = np.ones_like(y) if sigma_g is None else np.asarray(sigma_g, dtype=float)
    if sigma.shape != y.shape or not np.all(np.isfinite(sigma)) or np.any(sigma <= 0):
        raise TableCheckError("the standard errors of the means must be positive and finite, one per value")
    dof = 2 * len(a) - 6
    if dof < 1:
        raise TableCheckError(f"{len(a)} positions cannot determine 4 combinations and 2 offsets "
                              "(at least 4 positions with several outer and inner angles are needed)")
    whiten = _whitener(sigma, drift_g if weighted else 0.0, start_s, duration_s, correlation_time_s)
    p = np.zeros(4)
    offsets = np.zeros(2)
    iterations = 0
    for iterations in range(1, max_iterations + 1):
        design = _design(p, a)
        resid = y.ravel() - model_horizontal(p, a).ravel() - np.tile(offsets, len(a))
        dw = whiten(design)
        if iterations == 1:
            s = np.linalg.svd(dw, compute_uv=False)
            if s[-1] < 1e-9 * s[0]:
                raise TableCheckError("the positions cannot separate the table's tilts from the accelerometer "
                                      "offsets: use several outer and several inner angles (e.g. table-check-324)")
        step = np.linalg.lstsq(dw, whiten(resid), rcond=None)[0]
        p += step[:4]
        offsets += step[4:]
        if np.max(np.abs(step[:4])) < 1e-14:
            break
    design = _design(p, a)
    fitted = model_horizontal(p, a) + offsets
    residual = y - fitted
    chi2 = float(np.sum(whiten(residual.ravel()) ** 2))
    dw = whiten(design)
    cov = np.linalg.inv(dw.T @ dw)
    scale = max(1.0, chi2 / dof) if weighted else chi2 / dof
    cov = cov * scale
    sd = np.sqrt(np.diag(cov))
    if not relative_scale_uncertainty >= 0:
        raise TableCheckError(f"relative_scale_uncertainty must be >= 0, got {relative_scale_uncertainty!r}")
    noise_sd = sd[:4].copy()
    conversion_sd = relative_scale_uncertainty * np.repeat([np.hypot(p[0], p[1]), np.hypot(p[2], p[3])], 2)
    cov[:4, :4] += np.diag(conversion_sd ** 2)
    sd = np.sqrt(np.diag(cov))
    notes = []
    if weighted and chi2 / dof > 4.0:
        notes.append(f"the residuals exceed the standard errors of the means (reduced chi-square "
                     f"{chi2 / dof:.1f}): the uncertainties are scaled up by {math.sqrt(chi2 / dof):.2f}")
    obs = observability(a) if with_observability else None
    return TableCheckEstimate(a, y, sigma, COMBINATIONS, p.copy(), sd[:4], cov[:4, :4], offsets.copy(), sd[4:],
                              residual, chi2, dof, iterations, weighted, obs, notes, noise_sd, conversion_sd,
                              float(relative_scale_uncertainty))


# -- accelerometer outputs -> horizontal specific force ------------------------------------------

@dataclass(frozen=True)
class Conversion:
    """How counts/s became units of local g: per-axis scales (counts/s per g) and where they came from."""

    scale_counts_per_g: np.ndarray      # (3,)
    source: str
    calibrated: bool
    relative_uncertainty: float         # eps of `estimate`: common x/y scale and in-plane axis error


#: x/y scale taken from z, IMU axes uncorrected: the 1-sigma of the x/y pair's common scale error against z
#: (the z bias included) and of their axes' rotation about z when nothing better is known: a navigation-grade
#: triad's scale mismatch and misalignment are each typically below 1e-3 (a Type B bound, used as the 1-sigma)
NOMINAL_RELATIVE_UNCERTAINTY = 1e-3


def conversion_error(imu, local_g_mps2: float) -> tuple[float, float, float]:
    """(s, a, eps) of an IMU read the uncalibrated way (`horizontal_from_counts` without a calibration).

    The x/y outputs divided by the z output's scale per g act on the horizontal specific
    force as a 2x2 matrix M (x/y scales, in-plane axes, and the z bias in the divisor);
    the fit sees only its part that commutes with the inner frame's rotation, `(1 + s) I
    + a J`: a common scale error s and a rotation a of the tilt vectors (the rest, an x/y
    mismatch and shear, turns into residuals at twice the inner angle). `eps =
    sqrt((s^2 + a^2)/2)` is the per-component RMS relative error it causes over tilt
    directions: the `relative_uncertainty` this IMU would need to be stated with.
    """
    m = np.asarray(imu.acc_matrix, dtype=float)
    kz = float(m[2, 2] + imu.acc_scale[2] * imu.acc_bias[2] / local_g_mps2)      # z output / g with z up
    mh = m[:2, :2] / kz
    s = 0.5 * (mh[0, 0] + mh[1, 1]) - 1.0
    a = 0.5 * (mh[0, 1] - mh[1, 0])
    return float(s), float(a), math.sqrt(0.5 * (s * s + a * a))


def horizontal_from_counts(acc_mean, acc_sem, local_g_mps2: float, *, calibration=None,
                           relative_uncertainty: float = NOMINAL_RELATIVE_UNCERTAINTY,
                           ) -> tuple[np.ndarray, np.ndarray, Conversion]:
    """(K, 2) x/y specific force in units of local g, their 1-sigma, and how they were converted.

    `acc_mean`, `acc_sem` (K, 3) counts/s. With `calibration` (an `ImuCoefficients`)
    the full accelerometer model is inverted (scale, bias, axes). Without, x and y use
    the z accelerometer's scale measured here (mean z output / g: the z axis is up at
    every table-check position), i.e. a triad of alike accelerometers; that is good to
    the x/y/z scale mismatch and the in-plane misalignment (about 1e-3 each), a relative
    error of the tilts of that size (`relative_uncertainty`, the 1-sigma of that common
    scale error and of that rotation: `[imu.identity] acc_xy_to_z_uncertainty`, default
    `NOMINAL_RELATIVE_UNCERTAINTY`; `conversion_error` computes an IMU's own; passed on to
    `estimate` in `Conversion.relative_uncertainty`). A calibration's own uncertainty is
    not propagated (eps 0).
    """
    j = np.asarray(acc_mean, dtype=float)
    sem = np.asarray(acc_sem, dtype=float)
    if j.ndim != 2 or j.shape[1] != 3 or sem.shape != j.shape:
        raise TableCheckError(f"accelerometer means must be (K, 3) with standard errors alike, got {j.shape}")
    if calibration is not None:
        m = calibration.acc_matrix
        f = np.linalg.solve(m, (j - calibration.acc_scale * calibration.acc_bias).T).T / local_g_mps2
        scale = calibration.acc_scale * local_g_mps2
        return f[:, :2], sem[:, :2] / scale[:2], Conversion(scale, "the calibration's Ka, K0, Ea", True, 0.0)
    kz = float(np.mean(j[:, 2]))
    if not kz > 0:
        raise TableCheckError(f"the z accelerometer reads {kz:g} counts/s on average, not a positive value near "
                              "its scale: is the IMU mounted Z up (docs/explanation/model.md#frames)?")
    scale = np.full(3, kz)
    if not 0 <= relative_uncertainty < 1:
        raise TableCheckError(f"the x/y-to-z relative uncertainty must be in [0, 1), got {relative_uncertainty!r}")
    return j[:, :2] / kz, sem[:, :2] / kz, Conversion(scale, "z accelerometer's mean output / g (x, y assumed alike)",
                                                       False, float(relative_uncertainty))


__all__ = ["ANGLE_NAMES", "COMBINATIONS", "COMBINATION_KEYS", "Combination", "Conversion",
           "NOMINAL_RELATIVE_UNCERTAINTY", "Observability", "conversion_error",
           "TableCheckError", "TableCheckEstimate", "black_box_jacobian", "check_positions", "combination_matrix",
           "estimate", "horizontal_force", "horizontal_from_counts", "model_horizontal", "observability",
           "offset_columns", "true_combinations"]
