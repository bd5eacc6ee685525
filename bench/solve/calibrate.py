"""Solve a full calibration from observations and turn it into a result file."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from bench.model.earth import Site
from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES
from bench.model.imu import ImuCoefficients
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.quality_section import FitQuality, Outlier, QualitySection
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.run_section import RunInfo
from bench.model.units import ARCSEC, DEG_PER_HOUR
from bench.solve.budget import Budget, BudgetInputs, compute_budget
from bench.solve.methods import (
    GyroBias,
    LinearFit,
    SensorTriad,
    SolverError,
    gyro_bias_from_positions,
    solve_accelerometers,
    solve_gyros,
)
from bench.solve.significance import ExtendedFit

#: |residual| / sigma above which a step is flagged as an outlier.
OUTLIER_SIGMA = 4.0


@dataclass
class Calibration:
    """Solved triads plus what the result file needs."""

    accelerometers: SensorTriad | None
    gyros: SensorTriad | None
    gyro_bias: GyroBias | None
    positions: list[PositionObservation]
    rotations: list[RotationObservation]
    flags: list[str] = field(default_factory=list)
    #: the per-coefficient uncertainty budget; its combined uncertainty is each coefficient's sigma
    budget: Budget | None = None
    #: the higher-order families of `[model] terms` (`bench.solve.extended`), None: the 30-coefficient model
    extended: ExtendedFit | None = None

    def values_and_sigmas(self) -> tuple[dict[str, float], dict[str, float]]:
        """Solved coefficients in display units keyed by canonical name."""
        values: dict[str, float] = {}
        sigmas: dict[str, float] = {}

        def put(name: str, family: str, v: float, s: float) -> None:
            factor = RESULT_UNITS[family][1]
            values[name], sigmas[name] = v / factor, s / factor

        for triad, scale, axes_name, bias_name in ((self.accelerometers, "Ka", "Ea", "K0"),
                                                   (self.gyros, "Kg", "Eg", None)):
            if triad is None:
                continue
            sig = np.sqrt(np.diagonal(triad.cov, axis1=1, axis2=2))
            for i, s in enumerate(SENSOR_AXES):
                put(f"{scale}_{s}", scale, triad.scale[i], sig[i, 0])
                for j, a in enumerate(BODY_AXES):
                    put(f"{axes_name}_{a}{s}", axes_name, triad.axes[i, j], sig[i, 1 + j])
                if bias_name:
                    put(f"{bias_name}_{s}", bias_name, triad.bias[i], sig[i, 4])
        if self.gyro_bias is not None:
            for i, s in enumerate(SENSOR_AXES):
                put(f"D0_{s}", "D0", self.gyro_bias.value[i], self.gyro_bias.sigma[i])
        if self.budget is not None:
            for name in values:
                combined = self.budget.combined(name)
                if math.isfinite(combined):
                    sigmas[name] = combined
        if self.extended is not None:
            for name, value in self.extended.values.items():
                values[name], sigmas[name] = value, self.extended.sigma(name)
        return values, sigmas

    def _normalized(self, fit: str, fallback: np.ndarray) -> np.ndarray:
        """Residuals over the scatter the budget predicts (else over the fit's own noise)."""
        own = self.budget.normalized(fit) if self.budget is not None else None
        return fallback if own is None else own

    def residual_tables(self) -> dict[str, Any]:
        pos_rows = []
        for k, obs in enumerate(self.positions):
            row: dict[str, Any] = {"index": k, "label": obs.label, "angles_deg": list(obs.angles_deg)}
            if self.accelerometers is not None:
                row["acc_counts_per_s"] = _floats(self.accelerometers.fit.residuals[k])
                row["acc_normalized"] = _floats(self._normalized("accelerometers",
                                                                 self.accelerometers.fit.normalized)[k])
            if self.gyro_bias is not None:
                row["gyro_dph"] = _floats(self.gyro_bias.residuals[k] / DEG_PER_HOUR)
                row["gyro_normalized"] = _floats(self._normalized("gyro bias", self.gyro_bias.normalized)[k])
            pos_rows.append(row)
        rot_rows = []
        for k, turn in enumerate(self.rotations):
            row = {"index": k, "label": turn.label, "start_deg": list(turn.start_deg), "frame": turn.frame,
                   "direction": turn.direction, "revolutions": turn.revolutions}
            if self.gyros is not None:
                r = self.gyros.fit.residuals[k]
                row["gyro_counts"] = _floats(r)
                row["gyro_arcsec"] = _floats(r / self.gyros.scale / ARCSEC)
                row["gyro_normalized"] = _floats(self._normalized("gyros", self.gyros.fit.normalized)[k])
            rot_rows.append(row)
        return {"positions": pos_rows, "rotations": rot_rows}

    def quality(self) -> QualitySection:
        q = QualitySection(flags=list(self.flags), outlier_sigma=OUTLIER_SIGMA)
        if self.accelerometers and self.accelerometers.fit:
            q.accelerometers = _fit_quality(self.accelerometers.fit)
        if self.gyros and self.gyros.fit:
            q.gyros = _fit_quality(self.gyros.fit)
        if self.gyro_bias is not None:
            q.gyro_bias = FitQuality(chi2_per_dof=_floats(self.gyro_bias.chi2_per_dof),
                                     sigma_scaled=self.gyro_bias.scaled)
        outliers = []
        tables = self.residual_tables()
        for kind, rows in (("position", tables["positions"]), ("rotation", tables["rotations"])):
            for row in rows:
                for key in ("acc_normalized", "gyro_normalized"):
                    for axis, v in zip(SENSOR_AXES, row.get(key, [])):
                        if v is not None and abs(v) > OUTLIER_SIGMA:
                            sensor = "acc" if key.startswith("acc") else "gyro"
                            outliers.append(Outlier(step=kind, index=row["index"], sensor=f"{sensor}_{axis}",
                                                    normalized=v))
        q.outliers = outliers
        if self.budget is not None:
            q.uncertainty = self.budget.summary_json()
        if self.extended is not None:
            q.significance = self.extended.significance_json(self.budget.inputs.k if self.budget else 2.0)
        return q

    def to_result(self, run: RunInfo | Mapping[str, Any] | None = None,
                  sim_truth: ImuCoefficients | None = None) -> CalibrationResult:
        """The result of this calibration; `run` its run section, or that section's entries (read as a result
        file's: any may be missing; ResultFormatError when one is malformed)."""
        values, sigmas = self.values_and_sigmas()
        truth = None if sim_truth is None else coefficient_table(sim_truth.to_canonical())
        budgets = None
        if self.budget is not None:
            budgets = {name: self.budget.components.get(name, {}) for name in values}
            if self.extended is not None:
                budgets.update(self.extended.components)
        k = self.budget.inputs.k if self.budget is not None else None
        return CalibrationResult(coefficient_table(values, sigmas, budgets, k), self.residual_tables(), self.quality(),
                                 run if isinstance(run, RunInfo) else RunInfo.from_dict(run or {}, complete=False),
                                 truth)


def _fit_quality(fit: LinearFit) -> FitQuality:
    return FitQuality(chi2_per_dof=_floats(fit.chi2_per_dof), dof=fit.dof, weighted=fit.weighted,
                      sigma_scaled=fit.scaled)


def _floats(a) -> list[float | None]:
    return [float(x) if math.isfinite(x) else None for x in np.asarray(a, dtype=float)]


def solve(positions: list[PositionObservation], rotations: list[RotationObservation], site: Site,
          mounting=None, gyro_prior: ImuCoefficients | None = None,
          gyro_bias_stability: float = 0.0, acc_bias_stability: float = 0.0,
          budget_inputs: BudgetInputs | None = None,
          fitted_columns: dict[tuple[str, int], np.ndarray] | None = None) -> Calibration:
    """Accelerometers and gyro bias from positions, gyro scale/axes from rotations.

    Without rotations, `gyro_prior` (e.g. an earlier result) supplies Kg and Eg for the
    gyro bias; without either, the gyro bias is not solved and a flag says so.
    `*_bias_stability` (rad/s, m/s^2; the datasheet's bias instability) feed the budget's
    bias-instability part when `budget_inputs` (`bench.solve.budget`) is not given; every
    coefficient's sigma is the budget's combined standard uncertainty. `fitted_columns`: what an extended solve
    fitted beyond these (`compute_budget`), for the residual tests.
    """
    if not positions and not rotations:
        raise SolverError("nothing to solve: no position and no rotation observations")
    flags: list[str] = []
    acc = solve_accelerometers(positions, site, mounting) if positions else None
    gyros = None
    if rotations:
        noise_density = pooled_gyro_noise(positions)
        gyros = solve_gyros(rotations, site, mounting, noise_density=noise_density)
        if not all(o.gyro_integral_sigma is not None for o in rotations) and noise_density is None:
            flags.append("rotation uncertainties from residual scatter only (no static noise estimate)")
    bias = None
    if positions:
        source = gyros if gyros is not None else gyro_prior
        if source is None:
            flags.append("gyro bias not solved: no rotations and no prior gyro scale factors/axes")
        else:
            bias = gyro_bias_from_positions(positions, site, source, mounting)
    if budget_inputs is None:
        budget_inputs = BudgetInputs(gyro_bias_instability=gyro_bias_stability,
                                     acc_bias_instability=acc_bias_stability)
    budget = compute_budget(acc, gyros, bias, positions, rotations, site, budget_inputs, mounting, gyro_prior,
                            fitted_columns)
    flags += budget.flags
    return Calibration(acc, gyros, bias, list(positions), list(rotations), flags, budget)


def pooled_gyro_noise(positions: list[PositionObservation]) -> np.ndarray | None:
    """White-noise density of each gyro (counts/s * sqrt(s)) pooled over the static dwells.

    A dwell of length T with a mean known to sem has density sem * sqrt(T); a turn of
    length T' then integrates to a count with sigma density * sqrt(T').
    """
    sems = [(o.standard_error("gyro"), o.duration_s) for o in positions]
    densities = [sem ** 2 * duration for sem, duration in sems if sem is not None]
    if not densities:
        return None
    pooled = np.sqrt(np.mean(densities, axis=0))
    return pooled if np.all(pooled > 0) else None
