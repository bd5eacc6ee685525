"""The extended model's solve: the 30 coefficients and the higher-order families of `[model] terms`
(docs/explanation/extended-model.md; the families are `bench.model.extended`).

Every family enters the fit that observes it as extra columns of the same weighted least squares:
- accelerometers (positions): `J_s,k = p_s . f_k + q_s + Ka_s (Aa_s |f_s|/2 + Qa_s f_s^2 + Ca_js f_s f_j)`, the
  nominal specific force `f_k` along the sensor's nominal axis;
- accelerometer lever arms (turns about a vertical axis, where the specific force stays put in the body): the
  mean output over the turn's window less the positions' model at its attitude is `-Ka_s (1 - u_s^2) La_s
  int(w^2)/T` (two steps: the positions' parameters are carried into its sigma);
- gyros (turns): `int F_s = M_s . (d 2 pi N u + E) + c_s T + Kg_s (Ag_s |M_s . u|/2 + Ng_s u_s^2 int(w^2))
  + Kg_s Gg_s . int(f)`;
- the gyro-to-accelerometer time offset (turns across gravity in both directions, each carrying its samples'
  timing against the table's angle, `bench.model.turn_timing`): on its own, `bench.solve.time_offset`;
- gyro bias and g-sensitivity (positions): `F_s/Kg_s - Eg_s . w = D0_s + Gg_s . f` (the rotation fit and this one
  are iterated: each takes the other's g-sensitivity and scale factors).

The 30 coefficients, their budget and the residual test then come from the plain solve
(`bench.solve.calibrate.solve`) of the observations less the fitted higher-order parts: the weighted least squares
residual is orthogonal to every column, so the 30 values equal the extended fit's. Their noise component is the
extended fit's (larger: more unknowns share the data); the other components are the plain solve's. Each new
coefficient's budget has the sample noise and, for those from the positions, the bias instability; the table's
pointing error moves them only to second order and is not propagated.

Significance: per family, the Wald statistic `b^T C^-1 b` over its coefficients (all three sensors; C the fit's
covariance with the bias instability), chi-square with as many degrees of freedom as coefficients; for a linear
model this is the likelihood-ratio test of adding the family. `auto` starts from every family the plan observes
and drops the least significant one until all that remain pass at `ALPHA`.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Iterable

import numpy as np
from scipy.special import chdtrc  # the chi-square tail, without loading all of scipy's statistics

from bench.model.earth import Site
from bench.model.extended import FAMILIES, TERMS
from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES
from bench.model.imu import ImuCoefficients
from bench.model.kinematics import attitude
from bench.model.observations import PositionObservation, RotationObservation, turn_axis_in_body
from bench.model.units import DEG
from bench.solve.budget import (
    BIAS_INSTABILITY,
    CONSISTENCY_ALPHA,
    NOISE,
    TABLE,
    UNEXPLAINED,
    BudgetInputs,
    current_imu,
    gm_mean_kernel,
    observation_table_covariance,
)
from bench.solve.calibrate import Calibration, pooled_gyro_noise, solve
from bench.solve.methods import (
    LinearFit,
    SolverError,
    fit_per_sensor,
    nominal_position_inputs,
    pooled_sigma,
    rotation_design,
    scale_axes_bias,
    scale_axes_bias_jacobian,
)
from bench.solve.significance import ALPHA, ExtendedFit, FamilyTest
from bench.solve.time_offset import estimate_time_offset

#: the `[model] terms` value that lets the data choose
AUTO = "auto"
_ITERATIONS = 4
_VERTICAL = 0.9999          # |cos| between a turn's axis and gravity for the specific force to stay put


def parse_terms(terms: Iterable[str] | str) -> tuple[tuple[str, ...], bool]:
    """(families, auto) from `[model] terms` or `--model`: a list of family names, or "auto"."""
    if isinstance(terms, str):
        terms = [terms]
    terms = list(terms)
    if terms == [AUTO]:
        return TERMS, True
    unknown = [t for t in terms if t not in FAMILIES]
    if unknown:
        raise SolverError(f"unknown model term {unknown[0]!r}: choose from {', '.join(TERMS)} (or {AUTO!r})")
    return tuple(t for t in TERMS if t in terms), False


# -- the fits -------------------------------------------------------------------------------------------------

def _acc_columns(f: np.ndarray, s: int, terms: tuple[str, ...]) -> tuple[np.ndarray, list[tuple[str, str]]]:
    """Extra columns of accelerometer s at specific forces f (K, 3) and (family, coefficient) per column."""
    cols, names = [], []
    sensor = SENSOR_AXES[s]
    if "acc_asymmetry" in terms:
        cols.append(0.5 * np.abs(f[:, s]))
        names.append(("acc_asymmetry", f"Aa_{sensor}"))
    if "acc_second_order" in terms:
        cols.append(f[:, s] ** 2)
        names.append(("acc_second_order", f"Qa_{sensor}"))
    if "acc_cross" in terms:
        for j, axis in enumerate(BODY_AXES):
            if j != s:
                cols.append(f[:, s] * f[:, j])
                names.append(("acc_cross", f"Ca_{axis}{sensor}"))
    return (np.column_stack(cols) if cols else np.zeros((len(f), 0))), names


def _fit_one(design: np.ndarray, y: np.ndarray, sigma: np.ndarray | None, what: str) -> LinearFit:
    if np.linalg.matrix_rank(design, tol=1e-9 * max(np.abs(design).max(), 1e-300)) < design.shape[1]:
        raise SolverError(f"{what}: the plan does not observe the model's terms (rank-deficient design)")
    return fit_per_sensor(design, y[:, None], None if sigma is None else sigma[:, None])


def _operator(design: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    w = np.ones(len(design)) if sigma is None else 1.0 / sigma ** 2
    return np.linalg.solve(design.T @ (design * w[:, None]), design.T * w[None, :])


def _starts(observations) -> tuple[np.ndarray, np.ndarray]:
    """Each window's start and length (s); without starts, laid end to end."""
    starts = np.array([o.start_s if o.start_s is not None else math.nan for o in observations])
    durations = np.array([o.duration_s for o in observations])
    if not np.all(np.isfinite(starts)):
        starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]])
    return starts, durations


def _gm_kernel(positions: list[PositionObservation], tau: float) -> np.ndarray:
    return gm_mean_kernel(*_starts(positions), tau)


@dataclass
class _Part:
    """One fit's extended columns: params (count per column), covariance (with bias instability) and names."""

    names: list[tuple[str, str]]
    values_si: np.ndarray
    cov_si: np.ndarray           # full covariance of the extra columns, SI coefficients
    noise_var_si: np.ndarray     # diagonal, sample noise only
    #: budget component (bias instability, table) -> its diagonal variance
    other_var_si: dict[str, np.ndarray]


@dataclass
class _Solved:
    parts: list[_Part]
    positions: list[PositionObservation]
    rotations: list[RotationObservation]
    acc_fits: list[LinearFit] | None = None
    rot_fits: list[LinearFit] | None = None
    bias_fits: list[LinearFit] | None = None
    #: (fit, sensor) -> the columns fitted beyond the 30-coefficient design, for its residual tests
    columns: dict[tuple[str, int], np.ndarray] = dataclasses.field(default_factory=dict)


def _part(fit: LinearFit, design: np.ndarray, sigma: np.ndarray | None, first: int, names: list[tuple[str, str]],
          scale: float, extra: dict[str, np.ndarray | None]) -> _Part:
    """The extra columns `first:` of a single-sensor fit, divided by the sensor's scale into coefficients.

    Their covariance is the budget's: the sample noise plus each `extra` component (budget component -> the
    observations' covariance) pushed through the fit; the residuals are tested against the scatter that predicts
    (as `bench.solve.budget`'s residual test) and only an inconsistent fit adds the unexplained scatter."""
    operator = _operator(design, sigma)
    sl = slice(first, first + len(names))
    cov_noise = (fit.cov_noise if fit.cov_noise is not None else fit.cov)[0]
    c_y = np.diag(sigma ** 2) if sigma is not None else np.eye(len(design))
    full = cov_noise.copy()
    other: dict[str, np.ndarray] = {}
    for component, c_extra in extra.items():
        if c_extra is None:
            continue
        part = operator @ c_extra @ operator.T
        full = full + part
        c_y = c_y + c_extra
        other[component] = np.diag(part)[sl] / scale ** 2
    if sigma is None:
        full = fit.cov[0]                   # unweighted: the residual scatter sets the scale
    else:
        projector = np.eye(len(design)) - design @ operator
        c_r = projector @ c_y @ projector.T
        residual = fit.residuals[:, 0]
        dof = len(design) - design.shape[1]
        chi2 = float(residual @ np.linalg.pinv(c_r, rcond=1e-10) @ residual)
        if dof > 0 and chdtrc(dof, chi2) < CONSISTENCY_ALPHA:
            full = full * (chi2 / dof)      # the unexplained scatter: the whole random part scaled up
    return _Part(names, fit.params[0][sl] / scale, full[sl, sl] / scale ** 2, np.diag(cov_noise)[sl] / scale ** 2,
                 other)


@dataclass
class _Table:
    """The table's pointing error of the observations (`observation_table_covariance`) at the plain solve's IMU."""

    imu: ImuCoefficients | None
    obs: dict[str, np.ndarray]


def _table(positions, rotations, site: Site, inputs: BudgetInputs, mounting, gyro_prior) -> _Table:
    if inputs.table is None:
        return _Table(None, {})
    try:
        plain = solve(positions, rotations, site, mounting, gyro_prior, budget_inputs=BudgetInputs())
    except SolverError:
        return _Table(None, {})
    imu = current_imu(plain.accelerometers, plain.gyros, plain.gyro_bias, gyro_prior)
    angles = np.array([o.angles_deg for o in positions]).reshape(-1, 3)
    return _Table(imu, observation_table_covariance(imu, angles, rotations, site, inputs, mounting))


def _fit(positions: list[PositionObservation], rotations: list[RotationObservation], site: Site,
         terms: tuple[str, ...], inputs: BudgetInputs, mounting, gyro_prior: ImuCoefficients | None,
         table_error: _Table, lever_arm_m=None) -> _Solved:
    out = _Solved([], list(positions), list(rotations))
    table = table_error.obs
    acc_terms = tuple(t for t in terms if FAMILIES[t].sensor == "acc" and t not in ("acc_lever_arm", "time_offset"))
    gyro_terms = tuple(t for t in terms if FAMILIES[t].sensor == "gyro")
    angles = np.array([o.angles_deg for o in positions]) if positions else np.zeros((0, 3))
    f_nom, w_nom = nominal_position_inputs(angles, site, mounting)
    kernel = _gm_kernel(positions, inputs.correlation_time_s) if positions else None
    corrected_acc = np.array([o.acc_mean for o in positions]) if positions else np.zeros((0, 3))
    acc_scale = np.ones(3)
    acc_sigma = None
    # -- accelerometers at the positions
    if acc_terms or "acc_lever_arm" in terms:
        if not positions:
            raise SolverError("the accelerometer terms need positions")
        sems = [o.standard_error("acc") for o in positions]
        acc_sigma = pooled_sigma(np.array(sems), [o.duration_s for o in positions]) \
            if all(s is not None for s in sems) else None
        y = np.array([o.acc_mean for o in positions])
        out.acc_fits = []
        for s in range(3):
            extra, names = _acc_columns(f_nom, s, acc_terms)
            design = np.column_stack([f_nom, np.ones(len(f_nom)), extra])
            sig = None if acc_sigma is None else acc_sigma[:, s]
            fit = _fit_one(design, y[:, s], sig, f"accelerometer {SENSOR_AXES[s]}")
            out.acc_fits.append(fit)
            acc_scale[s] = float(np.linalg.norm(fit.params[0][:3]))
            c_gm = None if kernel is None else (acc_scale[s] * inputs.acc_bias_instability) ** 2 * kernel
            c_table = table["accelerometers"][s] if "accelerometers" in table else None
            if names:
                out.parts.append(_part(fit, design, sig, 4, names, acc_scale[s],
                                       {BIAS_INSTABILITY: c_gm, TABLE: c_table}))
                corrected_acc[:, s] -= extra @ fit.params[0][4:]
                out.columns[("accelerometers", s)] = extra
        if "acc_lever_arm" in terms:
            out.parts += _lever_arms(positions, rotations, site, acc_terms, out.acc_fits, acc_sigma, mounting,
                                     inputs, table_error.imu, lever_arm_m)
    # -- gyros: rotations and positions, iterated
    corrected_gyro = np.array([o.gyro_mean for o in positions]) if positions else np.zeros((0, 3))
    corrected_turns = np.array([o.gyro_integral for o in rotations]) if rotations else np.zeros((0, 3))
    if gyro_terms:
        gyro_parts, corrected_gyro, corrected_turns = _gyros(positions, rotations, site, gyro_terms, inputs,
                                                             mounting, gyro_prior, f_nom, w_nom, kernel, out, table)
        out.parts += gyro_parts
    if "time_offset" in terms:
        out.parts.append(_time_offset_part(rotations))
    out.positions = [dataclasses.replace(o, acc_mean=corrected_acc[k], gyro_mean=corrected_gyro[k])
                     for k, o in enumerate(positions)]
    out.rotations = [dataclasses.replace(o, gyro_integral=corrected_turns[k]) for k, o in enumerate(rotations)]
    return out


def _time_offset_part(rotations: list[RotationObservation]) -> _Part:
    """The time offset from the turns' timing (`bench.solve.time_offset`): the dwells' means and the turns'
    integrals do not see it, nor does it move them, so it is estimated on its own."""
    estimate = estimate_time_offset(rotations)
    noise = estimate.noise_sigma_s ** 2
    return _Part([("time_offset", "Dt")], np.array([estimate.value_s]), np.array([[estimate.sigma_s ** 2]]),
                 np.array([noise]), {})


def _lever_arms(positions, rotations, site: Site, acc_terms, acc_fits: list[LinearFit],
                acc_sigma: np.ndarray | None, mounting, inputs: BudgetInputs,
                imu: ImuCoefficients | None, lever_arm_m=None) -> list[_Part]:
    """Each accelerometer's own-axis lever arm from the turns about a vertical axis (two-step, see the module),
    beyond the unit's known place `lever_arm_m` (body axes, m; None: at the rotation centre)."""
    rows = []
    for o in rotations:
        if o.acc_integral is None or o.rate_sq_integral is None:
            continue
        u = turn_axis_in_body(o.start_deg, o.frame_index, mounting=mounting)
        f = attitude(np.asarray(o.start_deg, dtype=float) * DEG, mounting=mounting) @ site.specific_force_enu
        if abs(float(u @ f)) >= _VERTICAL * float(np.linalg.norm(f)):
            rows.append((o, u, f))
    if not rows:
        raise SolverError("acc_lever_arm: the plan has no turn about a vertical axis with its accelerometer sums")
    density2 = None
    if acc_sigma is not None:
        density2 = np.mean(acc_sigma ** 2 * np.array([o.duration_s for o in positions])[:, None], axis=0)
    # the bias drifting between the positions and the turns: one Gauss-Markov kernel over all their windows
    turn_obs = [o for o, _, _ in rows]
    starts, durations = _starts([*positions, *turn_obs])
    kernel_all = gm_mean_kernel(starts, durations, inputs.correlation_time_s)
    angles = np.array([o.angles_deg for o in positions])
    f_pos, _ = nominal_position_inputs(angles, site, mounting)
    # the table's pointing error at the positions and at the turns' attitudes, together
    every = np.concatenate([angles, np.array([o.start_deg for o in turn_obs])])
    table_all = observation_table_covariance(imu, every, [], site, inputs, mounting).get("accelerometers")
    known = None
    if lever_arm_m is not None:
        # the unit's known place: the mean centripetal force `w x (w x r)` over each turn, in body axes (the
        # tangential `dw/dt x r` integrates to nothing from rest to rest), out of the observations before the fit
        r = np.asarray(lever_arm_m, dtype=float)
        known = np.array([o.rate_sq_integral / o.duration_s * (float(u @ r) * u - r) for o, u, _ in rows])
    parts = []
    for s in range(3):
        fit = acc_fits[s]
        scale = float(np.linalg.norm(fit.params[0][:3]))
        f_rows = np.array([f for _, _, f in rows])
        extra, _ = _acc_columns(f_rows, s, acc_terms)
        x = np.column_stack([f_rows, np.ones(len(rows)), extra])
        durations = np.array([o.duration_s for o, _, _ in rows])
        y = np.array([o.acc_integral[s] for o, _, _ in rows]) / durations - x @ fit.params[0]
        if lever_arm_m is not None:
            y = y - known @ fit.params[0][:3]
        col = -(1.0 - np.array([u[s] ** 2 for _, u, _ in rows])) * np.array(
            [o.rate_sq_integral for o, _, _ in rows]) / durations * scale
        sig = None if density2 is None else np.sqrt(density2[s] / durations)
        one = _fit_one(col[:, None], y, sig, f"accelerometer {SENSOR_AXES[s]} lever arm")
        # the positions' parameters predicted every turn's output: their covariance enters the lever arm
        op = _operator(col[:, None], sig)
        carried = float((op @ x @ fit.cov[0] @ x.T @ op.T)[0, 0])
        carried_noise = float((op @ x @ (fit.cov_noise if fit.cov_noise is not None else fit.cov)[0] @ x.T
                               @ op.T)[0, 0])
        extra_p, _ = _acc_columns(f_pos, s, acc_terms)
        pos_op = _operator(np.column_stack([f_pos, np.ones(len(f_pos)), extra_p]),
                           None if acc_sigma is None else acc_sigma[:, s])
        left = np.hstack([-(x @ pos_op), np.eye(len(rows))])       # turn residuals from [positions, turns]
        c_gm = (scale * inputs.acc_bias_instability) ** 2 * (left @ kernel_all @ left.T)
        gm = float((op @ c_gm @ op.T)[0, 0])
        table_var = 0.0 if table_all is None else float((op @ left @ table_all[s] @ left.T @ op.T)[0, 0])
        var = float(one.cov[0, 0, 0]) + carried + gm + table_var
        noise = float((one.cov_noise if one.cov_noise is not None else one.cov)[0, 0, 0]) + carried_noise
        parts.append(_Part([("acc_lever_arm", f"La_{SENSOR_AXES[s]}")], one.params[0].copy(), np.array([[var]]),
                           np.array([noise]), {BIAS_INSTABILITY: np.array([gm]), TABLE: np.array([table_var])}))
    return parts


def _gyros(positions, rotations, site: Site, terms, inputs: BudgetInputs, mounting,
           gyro_prior: ImuCoefficients | None, f_nom, w_nom, kernel, out: _Solved, table: dict[str, np.ndarray]):
    turn_terms = [t for t in terms if t in ("gyro_asymmetry", "gyro_nonlinearity")]
    if turn_terms and not rotations:
        raise SolverError(f"{turn_terms[0]} needs turns")
    g_sens = "gyro_g_sensitivity" in terms
    if g_sens and not positions:
        raise SolverError("gyro_g_sensitivity needs positions")
    if not rotations and gyro_prior is None:
        raise SolverError("gyro_g_sensitivity needs turns or a prior gyro scale factor")
    base = rotation_design(rotations, site, mounting) if rotations else np.zeros((0, 4))
    extra_cols = []
    for s in range(3):
        cols = []
        if "gyro_asymmetry" in terms:
            cols.append(0.5 * np.abs(base[:, s]))
        if "gyro_nonlinearity" in terms:
            if any(o.rate_sq_integral is None for o in rotations):
                raise SolverError("gyro_nonlinearity: a turn lacks its squared-rate integral")
            axes = np.array([turn_axis_in_body(o.start_deg, o.frame_index, mounting=mounting) for o in rotations])
            cols.append(axes[:, s] ** 2 * np.array([o.rate_sq_integral for o in rotations]))
        extra_cols.append(np.column_stack(cols) if cols else np.zeros((len(rotations), 0)))
    # the specific force integrated over each turn (body axes): its axial part, exact for a vertical axis
    force = []
    for o in rotations:
        u = turn_axis_in_body(o.start_deg, o.frame_index, mounting=mounting)
        f = attitude(np.asarray(o.start_deg, dtype=float) * DEG, mounting=mounting) @ site.specific_force_enu
        force.append(o.duration_s * float(u @ f) * u)
    force_integral = np.array(force).reshape(-1, 3)
    y_turns = np.array([o.gyro_integral for o in rotations]).reshape(-1, 3)
    rot_sigma = _turn_sigma(positions, rotations)
    f_out = np.array([o.gyro_mean for o in positions]).reshape(-1, 3)
    sems = [o.standard_error("gyro") for o in positions]
    have_sem = bool(positions) and all(s is not None for s in sems)
    g_matrix = np.zeros((3, 3))
    extra_params = [np.zeros(extra_cols[s].shape[1]) for s in range(3)]
    scale, axes = (gyro_prior.gyro_scale, gyro_prior.gyro_axes) if gyro_prior is not None \
        else (np.ones(3), np.eye(3))
    rot_fits: list[LinearFit] = []
    bias_fits: list[LinearFit] = []
    asym = np.zeros(3)
    nonlin = np.zeros(3)
    for _pass in range(_ITERATIONS):
        if rotations:
            rot_fits = []
            for s in range(3):
                design = np.column_stack([base, extra_cols[s]])
                # the g-sensitivity of the previous pass (none in the first) with its scale factor
                target = y_turns[:, s] - (scale[s] * (force_integral @ g_matrix[s]) if g_matrix[s].any() else 0.0)
                rot_fits.append(_fit_one(design, target, None if rot_sigma is None else rot_sigma[:, s],
                                         f"gyro {SENSOR_AXES[s]} (turns)"))
            params = np.array([f.params[0] for f in rot_fits])
            scale, axes, _bias = scale_axes_bias(params[:, :4])
            for s in range(3):
                extra_params[s] = params[s, 4:]
                k = 0
                if "gyro_asymmetry" in terms:
                    asym[s] = params[s, 4 + k] / scale[s]
                    k += 1
                if "gyro_nonlinearity" in terms:
                    nonlin[s] = params[s, 4 + k] / scale[s]
        if not positions:
            break
        u_rest = w_nom @ axes.T
        z = f_out / scale - u_rest - (0.5 * asym * np.abs(u_rest) + nonlin * u_rest ** 2)
        sigma = pooled_sigma(np.array(sems), [o.duration_s for o in positions]) / scale if have_sem else None
        design_b = np.column_stack([np.ones(len(positions)), f_nom]) if g_sens else np.ones((len(positions), 1))
        bias_fits = [_fit_one(design_b, z[:, s], None if sigma is None else sigma[:, s],
                              f"gyro {SENSOR_AXES[s]} bias") for s in range(3)]
        if g_sens:
            g_matrix = np.array([f.params[0][1:4] for f in bias_fits])
        if not rotations or not g_sens:
            break
    out.rot_fits = rot_fits or None
    out.bias_fits = bias_fits or None
    for s in range(3):
        if rotations and turn_terms:
            out.columns[("gyros", s)] = extra_cols[s]
        if positions and g_sens:
            out.columns[("gyro bias", s)] = f_nom
    parts: list[_Part] = []
    turn_kernel = None
    if rotations:
        starts, durations = _starts(rotations)
        turn_kernel = gm_mean_kernel(starts, durations, inputs.correlation_time_s) * np.outer(durations, durations)
    for s in range(3):
        sensor = SENSOR_AXES[s]
        if rotations and turn_terms:
            names = [(t, f"{FAMILIES[t].key}_{sensor}") for t in turn_terms]
            design = np.column_stack([base, extra_cols[s]])
            # each column carries its coefficient times Kg (the asymmetry's column is |.|/2); the bias drifting
            # between the turns (a Gauss-Markov bias, as the budget's) enters as their integrals' covariance
            c_turn_gm = (scale[s] * inputs.gyro_bias_instability) ** 2 * turn_kernel
            parts.append(_part(rot_fits[s], design, None if rot_sigma is None else rot_sigma[:, s], 4,
                               names, float(scale[s]), {BIAS_INSTABILITY: c_turn_gm,
                                                        TABLE: table["gyros"][s] if "gyros" in table else None}))
        if g_sens:
            names = [("gyro_g_sensitivity", f"Gg_{a}{sensor}") for a in BODY_AXES]
            sig = None if not have_sem else pooled_sigma(np.array(sems), [o.duration_s for o in positions])[:, s] \
                / scale[s]
            c_gm = None if kernel is None else inputs.gyro_bias_instability ** 2 * kernel
            c_table = table["gyro bias"][s] / scale[s] ** 2 if "gyro bias" in table else None
            parts.append(_part(bias_fits[s], design_b, sig, 1, names, 1.0,
                               {BIAS_INSTABILITY: c_gm, TABLE: c_table}))
    # the observations less the fitted higher-order parts
    u_rest = w_nom @ axes.T
    gyro_positions = f_out - scale * (f_nom @ g_matrix.T + 0.5 * asym * np.abs(u_rest) + nonlin * u_rest ** 2) \
        if positions else f_out
    turns = y_turns.copy()
    for s in range(3):
        if rotations:
            turns[:, s] -= scale[s] * (force_integral @ g_matrix[s]) + extra_cols[s] @ extra_params[s]
    return parts, gyro_positions, turns


def _turn_sigma(positions, rotations) -> np.ndarray | None:
    """Each turn integral's 1-sigma (counts): its own, else the dwells' pooled density * sqrt(T)."""
    if not rotations:
        return None
    if all(o.gyro_integral_sigma is not None for o in rotations):
        return np.array([o.gyro_integral_sigma for o in rotations])
    density = pooled_gyro_noise(positions)
    if density is None:
        return None
    return np.array([density * math.sqrt(o.duration_s) for o in rotations])


# -- the solve ------------------------------------------------------------------------------------------------

def _tests(parts: list[_Part], terms: tuple[str, ...]) -> dict[str, FamilyTest]:
    stat = dict.fromkeys(terms, 0.0)
    dof = dict.fromkeys(terms, 0)
    for part in parts:
        families = [fam for fam, _ in part.names]
        for term in set(families):
            idx = [i for i, fam in enumerate(families) if fam == term]
            b = part.values_si[idx]
            c = part.cov_si[np.ix_(idx, idx)]
            stat[term] += float(b @ np.linalg.pinv(c) @ b)
            dof[term] += len(idx)
    return {t: FamilyTest(t, stat[t], dof[t], float(chdtrc(dof[t], stat[t])) if dof[t] else math.nan)
            for t in terms}


def _observed(positions, rotations, site: Site, terms: tuple[str, ...], inputs: BudgetInputs, mounting,
              gyro_prior, table: _Table, lever_arm_m=None) -> tuple[tuple[str, ...], dict[str, str]]:
    """The families the plan observes together, added one at a time in `TERMS` order; the others with why not."""
    kept: list[str] = []
    left: dict[str, str] = {}
    for term in terms:
        try:
            _fit(positions, rotations, site, (*kept, term), inputs, mounting, gyro_prior, table, lever_arm_m)
        except SolverError as exc:
            left[term] = f"not observed by this plan together with {', '.join(kept) or 'the 30'} ({exc})"
            continue
        kept.append(term)
    return tuple(kept), left


def solve_extended(positions: list[PositionObservation], rotations: list[RotationObservation], site: Site,
                   terms: Iterable[str] | str, mounting=None, gyro_prior: ImuCoefficients | None = None,
                   budget_inputs: BudgetInputs | None = None, lever_arm_m=None) -> Calibration:
    """The calibration with the higher-order families `terms` (or "auto", see the module); no terms: `solve`.
    `lever_arm_m`: the unit's known place from the rotation centre (body axes, m), whose centripetal force the
    lever-arm fit takes out of the turns (the other fits use no accelerometer output from a turn)."""
    families, auto = parse_terms(terms)
    inputs = budget_inputs or BudgetInputs()
    if not families:
        return solve(positions, rotations, site, mounting, gyro_prior, budget_inputs=inputs)
    left: dict[str, str] = {}
    table = _table(positions, rotations, site, inputs, mounting, gyro_prior)
    if auto:
        families, left = _observed(positions, rotations, site, families, inputs, mounting, gyro_prior, table,
                                   lever_arm_m)
        while families:
            solved = _fit(positions, rotations, site, families, inputs, mounting, gyro_prior, table, lever_arm_m)
            tests = _tests(solved.parts, families)
            weakest = max(families, key=lambda t: tests[t].p_value)
            if tests[weakest].significant():
                break
            left[weakest] = f"not significant (p = {tests[weakest].p_value:.2g} >= {ALPHA:g})"
            families = tuple(t for t in families if t != weakest)
        if not families:
            calibration = solve(positions, rotations, site, mounting, gyro_prior, budget_inputs=inputs)
            calibration.extended = ExtendedFit((), left_out=left, auto=True)
            return calibration
    solved = _fit(positions, rotations, site, families, inputs, mounting, gyro_prior, table, lever_arm_m)
    calibration = solve(solved.positions, solved.rotations, site, mounting, gyro_prior, budget_inputs=inputs,
                        fitted_columns=solved.columns)
    calibration.positions, calibration.rotations = list(positions), list(rotations)
    fit = ExtendedFit(families, tests=_tests(solved.parts, families), left_out=left, auto=auto)
    for part in solved.parts:
        for i, (term, name) in enumerate(part.names):
            factor = FAMILIES[term].result_to_si
            fit.values[name] = float(part.values_si[i]) / factor
            comps = {NOISE: math.sqrt(part.noise_var_si[i]) / factor}
            scaled = float(part.cov_si[i, i]) - float(part.noise_var_si[i])
            for component, var in part.other_var_si.items():
                scaled -= float(var[i])
                if var[i] > 0:
                    comps[component] = math.sqrt(var[i]) / factor
            if scaled > 1e-12 * float(part.cov_si[i, i]):
                comps[UNEXPLAINED] = math.sqrt(scaled) / factor
            fit.components[name] = comps
    fit.noise_30 = _noise_30(solved, calibration)
    if calibration.budget is not None:
        for name, sigma in fit.noise_30.items():
            if name in calibration.budget.components:
                calibration.budget.components[name][NOISE] = sigma
    calibration.extended = fit
    return calibration


def _noise_30(solved: _Solved, calibration: Calibration) -> dict[str, float]:
    """The 30 coefficients' sample-noise sigma under the extended fits (display units)."""
    out: dict[str, float] = {}

    def put(name: str, family: str, var: float) -> None:
        out[name] = math.sqrt(max(var, 0.0)) / RESULT_UNITS[family][1]

    for fits, scale_key, axes_key, bias_key in ((solved.acc_fits, "Ka", "Ea", "K0"), (solved.rot_fits, "Kg", "Eg",
                                                                                       None)):
        if not fits:
            continue
        for s, fit in enumerate(fits):
            cov = (fit.cov_noise if fit.cov_noise is not None else fit.cov)[0][:4, :4]
            jac = scale_axes_bias_jacobian(fit.params[0][:4])
            var = np.diag(jac @ cov @ jac.T)
            sensor = SENSOR_AXES[s]
            put(f"{scale_key}_{sensor}", scale_key, var[0])
            for j, a in enumerate(BODY_AXES):
                put(f"{axes_key}_{a}{sensor}", axes_key, var[1 + j])
            if bias_key:
                put(f"{bias_key}_{sensor}", bias_key, var[4])
    bias = calibration.gyro_bias
    if solved.bias_fits and bias is not None:
        for s, fit in enumerate(solved.bias_fits):
            bias_var = float((fit.cov_noise if fit.cov_noise is not None else fit.cov)[0][0, 0])
            if solved.rot_fits and bias.dd_dm is not None:
                rot = solved.rot_fits[s]
                m_cov = (rot.cov_noise if rot.cov_noise is not None else rot.cov)[0][:3, :3]
                bias_var += float(bias.dd_dm[s] @ m_cov @ bias.dd_dm[s])
            put(f"D0_{SENSOR_AXES[s]}", "D0", bias_var)
    return out


__all__ = ["ALPHA", "AUTO", "ExtendedFit", "FamilyTest", "parse_terms", "predicted_sigmas", "solve_extended"]


def predicted_sigmas(positions: list[PositionObservation], rotations: list[RotationObservation], site: Site,
                     terms: Iterable[str], mounting=None, gyro_prior: ImuCoefficients | None = None,
                     budget_inputs: BudgetInputs | None = None) -> dict[str, float]:
    """The sample-noise 1-sigma (result units) of each coefficient of the families `terms` on these observations
    (their values do not matter, only their weights and the plan's geometry); SolverError if the plan does not
    observe them together."""
    families, _ = parse_terms(terms)
    inputs = budget_inputs or BudgetInputs()
    solved = _fit(positions, rotations, site, families, inputs, mounting, gyro_prior, _Table(None, {}))
    out: dict[str, float] = {}
    for part in solved.parts:
        for i, (term, name) in enumerate(part.names):
            out[name] = math.sqrt(float(part.noise_var_si[i])) / FAMILIES[term].result_to_si
    return out
