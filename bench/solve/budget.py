"""Per-coefficient uncertainty budget (GUM): components, combined and expanded uncertainty.

Every solved coefficient is a linear function, to first order, of the observations
(per-position means, per-turn integrals): `theta = J P y` with `P` the weighted least
squares operator of its fit and `J` the Jacobian from (p, q) to (scale, axes, bias).
Each error source is written as a covariance `C_y` of the observations (or, for the
turntable, propagated through the whole solve) and contributes `J P C_y P^T J^T`:

- **noise** (Type A): the per-step sample noise the fit was weighted by (block-mean
  standard errors of the dwells, white-noise density * sqrt(T) for the turns); never
  scaled by the residuals (see **consistency** below).
- **bias instability** (Type B, the datasheet's or `bench noise`'s bias instability B):
  a first-order Gauss-Markov bias of 1-sigma B and correlation time tau, so two steps
  `i`, `j` share `B^2 <k(t, s)>` (the kernel `exp(-|t - s|/tau)` averaged over both
  windows): drift that is common to the run looks like bias, drift between steps
  scatters like noise.
- **turntable pointing** (Type B): the nine black-box angles with a 1-sigma prior
  each (`[table] pointing_accuracy_arcsec` or a table-check result), pushed through the
  plan's own solve: first order `sum_j (d theta/d angle_j * sigma_j)^2` by central
  differences, plus the second-order rest by Monte Carlo (the mean square of the exact
  error minus its linear part over draws), so a plan that cancels an angle to first
  order is credited for it.
- **local gravity** and **latitude** (Type B): the configured site's uncertainty,
  propagated by central differences through the same solve.
- **count resolution** (Type B): a turn's integral is a difference of two counter
  readings, each known to one count (1/sqrt(6) counts for the difference of two
  uniform remainders). A dwell's mean has its resolution floor in its standard error.
  An IMU that sends each sample's value rounded on its own (sbg-ecan: 0.001 rad/s) has
  no exact sum: the rounding that its own noise does not dither away stays in a turn's
  integral (`RotationObservation.rounding_var`) and in a dwell's standard error
  (`bench.model.observations.rounding_bias_variance`); the dithered rest is white noise,
  in the samples' scatter.
- **turn angle** (Type B, `[table] turn_angle_error_arcsec`): the solve takes each turn
  as exactly N revolutions; the table stops at each end only to its position
  repeatability (servo in-position band, readback resolution), so a turn's angle is off
  by delta_k, independent between turns, and its integral by `M (d u_k) delta_k`: the
  observation covariance `diag((M_s . d u_k)^2 sigma^2)` per gyro s. An encoder error that
  depends on the angle alone cancels (a turn starts and ends at the same angle mod 360).

The combined standard uncertainty is the root-sum-square (the sources are independent);
the expanded uncertainty is k = 2 times it. The turn's rate error does not enter: the
integral runs rest to rest, so only the angle turned matters (above).

**Consistency.** The same sources predict the covariance of the fit residuals
`r = (I - A P) y`: `C_r = (I - A P) C_y (I - A P)^T`. The observed residuals are tested
with `chi2 = r^T C_r^+ r` on K - 4 degrees of freedom (0.1 % level per sensor and fit,
about 1 % for the nine tests of a calibration): only a real
inconsistency (a wrong model, a moved IMU, a bad step) is flagged, naming the steps
whose normalised residuals drive it, and only then is an extra "unexplained scatter"
component added (a flagged fallback), `sqrt(chi2/dof - 1)` times the random part.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np
from scipy.special import chdtrc

from bench.model.closed_form import position_outputs, turn_closed_form, turn_integrals
from bench.model.earth import Site
from bench.model.families import BODY_AXES, RESULT_UNITS, SENSOR_AXES
from bench.model.imu import ImuCoefficients
from bench.model.observations import (
    COUNT_RESOLUTION,
    PositionObservation,
    RotationObservation,
    rounding_bias_variance,
    turn_axis_in_body,
)
from bench.model.table_prior import TablePrior
from bench.model.units import ARCSEC
from bench.solve.methods import (
    GyroBias,
    SensorTriad,
    nominal_position_inputs,
    pooled_sigma,
    position_design,
    rotation_design,
    scale_axes_bias,
    scale_axes_bias_jacobian,
)

#: coverage factor of the expanded uncertainty
K_EXPANDED = 2.0
#: level of each residual test: nine tests per calibration (three fits x three sensors) keep
#: the chance of a false alarm on a consistent calibration near 1 %
CONSISTENCY_ALPHA = 0.001
NOISE, BIAS_INSTABILITY, TABLE, GRAVITY, LATITUDE, RESOLUTION, TURN_ANGLE, UNEXPLAINED = (
    "noise", "bias instability", "turntable pointing", "local gravity", "latitude", "count resolution",
    "turn angle", "unexplained scatter")
#: component -> (GUM type, what it comes from)
SOURCES = {
    NOISE: ("A", "sample noise of the dwells and turns"),
    BIAS_INSTABILITY: ("B", "bias instability (Gauss-Markov) over the run"),
    TABLE: ("B", "turntable pointing (black-box angles), first and second order"),
    GRAVITY: ("B", "local gravity"),
    LATITUDE: ("B", "site latitude"),
    RESOLUTION: ("B", "IMU output resolution of the turn integrals (counter, or each sample's rounding)"),
    TURN_ANGLE: ("B", "each turn's angle error (the table's position repeatability at its ends)"),
    UNEXPLAINED: ("A", "residual scatter the budget does not explain (fallback scaling)"),
}
#: The components every calibration on one bench shares (the same table and its black box, the same site): a
#: calibration of one IMU at several temperatures (`bench.thermal`) has the same error from them at each. The
#: others (noise, bias instability, count resolution, unexplained scatter) are each run's own.
COMMON_SOURCES = (TABLE, GRAVITY, LATITUDE)


def common_sigma(components: Mapping[str, float]) -> float:
    """The part of a coefficient's combined uncertainty (its budget `components`, display units) that every
    calibration on the same bench shares (`COMMON_SOURCES`, root-sum-square); the rest is independent."""
    return math.sqrt(sum(v * v for c, v in components.items() if c in COMMON_SOURCES and math.isfinite(v)))


_STEP_RAD = 1.0 * ARCSEC
_QUANT_VAR = 1.0 / 6.0      # variance (counts^2) of the difference of two uniform remainders


@dataclass(frozen=True)
class BudgetInputs:
    """What is known about the equipment beyond the data (SI)."""

    table: TablePrior | None = None
    gyro_bias_instability: float = 0.0      # rad/s, 1-sigma of the Gauss-Markov bias
    acc_bias_instability: float = 0.0       # m/s^2
    correlation_time_s: float = 300.0
    gravity_sigma_mps2: float = 0.0
    latitude_sigma_deg: float = 0.0
    count_resolution: float = COUNT_RESOLUTION
    turn_rate_dps: float = 10.0             # the closed-form turns of the table part
    #: (label, deg/s) of the turns with their own rate (a version-2 rotations schedule); the others turn at
    #: `turn_rate_dps`
    turn_rates_dps: tuple[tuple[str, float], ...] = ()
    turn_angle_sigma_rad: float | None = None   # 1-sigma of each turn's angle error; None: not known
    mc_draws: int = 200
    seed: int = 0
    k: float = K_EXPANDED

    def rates_of(self, rotations) -> np.ndarray:
        """Each turn's rate (deg/s), by its label: its own, else `turn_rate_dps`."""
        own = dict(self.turn_rates_dps)
        return np.array([own.get(o.label, self.turn_rate_dps) for o in rotations], dtype=float)

    def to_json(self) -> dict[str, Any]:
        return {"table": None if self.table is None else self.table.to_json(),
                "gyro_bias_instability_dph": self.gyro_bias_instability / RESULT_UNITS["D0"][1],
                "acc_bias_instability_g": self.acc_bias_instability / RESULT_UNITS["K0"][1],
                "correlation_time_s": self.correlation_time_s, "gravity_sigma_mps2": self.gravity_sigma_mps2,
                "latitude_sigma_deg": self.latitude_sigma_deg, "count_resolution": self.count_resolution,
                "turn_angle_error_arcsec": (None if self.turn_angle_sigma_rad is None
                                            else self.turn_angle_sigma_rad / ARCSEC),
                "mc_draws": self.mc_draws, "k": self.k}


@dataclass
class Consistency:
    """The residual test of one sensor's fit against the residual scatter the budget predicts."""

    fit: str                    # "accelerometers" | "gyros" | "gyro bias"
    sensor: str                 # "x" | "y" | "z"
    chi2: float
    dof: int
    p_value: float
    normalized: np.ndarray      # (K,) residual / its predicted 1-sigma
    labels: list[str]
    scale: float = 1.0          # the fallback factor sqrt(chi2/dof) applied, 1 when consistent

    @property
    def consistent(self) -> bool:
        return not (self.dof > 0 and self.p_value < CONSISTENCY_ALPHA)

    def describe(self) -> str:
        """One line: which fit and sensor, how far off, the steps driving it."""
        return (f"{self.fit} {self.sensor}: residuals inconsistent with the uncertainty budget (chi2/dof "
                f"{self.chi2 / self.dof:.3g} on {self.dof} dof, p = {self.p_value:.2g}), driven by "
                f"{', '.join(self.drivers())}")

    def drivers(self, count: int = 3) -> list[str]:
        """The steps with the largest normalised residuals, e.g. 'P07 (+5.2)'."""
        order = np.argsort(-np.abs(np.nan_to_num(self.normalized)))[:count]
        return [f"{self.labels[i]} ({self.normalized[i]:+.1f})" for i in order]

    def to_json(self) -> dict[str, Any]:
        return {"fit": self.fit, "sensor": self.sensor, "chi2": _f(self.chi2), "dof": self.dof,
                "p_value": _f(self.p_value), "consistent": self.consistent, "scale": _f(self.scale),
                "drivers": [] if self.consistent else self.drivers()}


def _f(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


@dataclass
class Budget:
    """Per coefficient (canonical name): component -> standard uncertainty, display units."""

    components: dict[str, dict[str, float]]
    consistency: list[Consistency]
    inputs: BudgetInputs
    flags: list[str] = field(default_factory=list)

    @property
    def table_included(self) -> bool:
        return self.inputs.table is not None

    def combined(self, name: str) -> float:
        parts = self.components.get(name)
        if not parts:
            return math.nan
        return math.sqrt(sum(v * v for v in parts.values()))

    def expanded(self, name: str) -> float:
        return self.inputs.k * self.combined(name)

    def inconsistent(self) -> list[Consistency]:
        return [c for c in self.consistency if not c.consistent]

    def normalized(self, fit: str) -> np.ndarray | None:
        """(K, 3) residuals of a fit normalised by their predicted scatter, or None."""
        rows = [c for c in self.consistency if c.fit == fit]
        if len(rows) != 3:
            return None
        return np.stack([c.normalized for c in rows], axis=1)

    def summary_json(self) -> dict[str, Any]:
        return {"k": self.inputs.k, "table_included": self.table_included,
                "turn_angle_included": self.inputs.turn_angle_sigma_rad is not None, "inputs": self.inputs.to_json(),
                "components": {name: {"type": SOURCES[name][0], "source": SOURCES[name][1]}
                               for name in SOURCES},
                "consistency": [c.to_json() for c in self.consistency], "flags": list(self.flags)}


def probe_boxes(step_rad: float) -> np.ndarray:
    """(18, 3, 3): +step then -step on each of the nine angles."""
    boxes = np.zeros((18, 3, 3))
    for j in range(9):
        boxes[j].flat[j] = step_rad
        boxes[9 + j].flat[j] = -step_rad
    return boxes


def rotation_design_nominal(turns, site: Site, rate_dps, mounting=None) -> np.ndarray:
    """`[d 2 pi N u + E, T]` (K, 4) of constant-rate turns on an ideal table (an IMU mounted with `mounting`)."""
    rot, earth, durations = turn_closed_form(turns, site, rate_dps, mounting=mounting)
    return np.column_stack([rot + earth, durations])


# -- the Gauss-Markov kernel ------------------------------------------------------------------

def gm_mean_kernel(start_s: np.ndarray, duration_s: np.ndarray, tau_s: float) -> np.ndarray:
    """(K, K): `<exp(-|t - s|/tau)>` with t over window i and s over window j (windows disjoint or equal)."""
    a = np.asarray(start_s, dtype=float)
    t = np.asarray(duration_s, dtype=float)
    x = t / tau_s
    # the same window: 2/x^2 (x - 1 + e^-x)
    same = np.where(x > 1e-6, 2.0 / np.maximum(x, 1e-300) ** 2 * (x - 1.0 + np.exp(-x)), 1.0 - x / 3.0)
    # disjoint windows: tau^2 (1 - e^-xi)(1 - e^-xj) e^-(gap/tau) / (Ti Tj)
    g = np.where(x > 1e-9, -np.expm1(-x) / np.maximum(x, 1e-300), 1.0)
    end = a + t
    gap = np.maximum(a[None, :] - end[:, None], a[:, None] - end[None, :])
    k = g[:, None] * g[None, :] * np.exp(-np.maximum(gap, 0.0) / tau_s)
    np.fill_diagonal(k, same)
    return k


def _times(observations) -> tuple[np.ndarray, np.ndarray]:
    """Start times and durations; steps without a start time are laid end to end in order."""
    durations = np.array([o.duration_s for o in observations], dtype=float)
    starts = [o.start_s for o in observations]
    if any(s is None for s in starts):
        starts = np.concatenate([[0.0], np.cumsum(durations)[:-1]]).tolist()
    return np.array(starts, dtype=float), durations


# -- linear propagation through one fit ------------------------------------------------------------

def _operator(design: np.ndarray, sigma: np.ndarray | None) -> np.ndarray:
    """(P, K): the least-squares operator of a fit weighted by `sigma` (K,) (None: equal weights)."""
    w = np.ones(len(design)) if sigma is None else 1.0 / sigma
    aw = design * w[:, None]
    return np.linalg.solve(aw.T @ aw, aw.T * w[None, :])


def _triad_var(triad: SensorTriad, design: np.ndarray, s: int, c_y: np.ndarray) -> np.ndarray:
    """(5,) variances of (scale, axes, bias) of sensor s for observation covariance c_y (K, K)."""
    p = _operator(design, None if triad.fit.sigma is None else triad.fit.sigma[:, s])
    jac = scale_axes_bias_jacobian(triad.fit.params[s])
    return np.diag(jac @ p @ c_y @ p.T @ jac.T).copy()


def _consistency(fit: str, s: int, design: np.ndarray, sigma: np.ndarray | None, residual: np.ndarray,
                 c_y: np.ndarray, labels: list[str]) -> Consistency:
    p = _operator(design, sigma)
    resid_op = np.eye(len(design)) - design @ p
    c_r = resid_op @ c_y @ resid_op.T
    c_r = 0.5 * (c_r + c_r.T)
    vals, vecs = np.linalg.eigh(c_r)
    dof = len(design) - design.shape[1]
    keep = vals > 1e-12 * max(vals.max(), 1e-300)
    proj = vecs[:, keep].T @ residual
    chi2 = float(np.sum(proj ** 2 / vals[keep])) if keep.any() else math.nan
    p_value = float(chdtrc(dof, chi2)) if dof > 0 and math.isfinite(chi2) else math.nan
    diag = np.diag(c_r)
    # a step the fit follows exactly (leverage 1: a turn pair that alone fixes an extended family) has no residual
    # scatter: rounding leaves ~1e-16 of it, which would make its ~1e-10 residual look like a 1e5-sigma outlier
    with np.errstate(invalid="ignore", divide="ignore"):
        normalized = np.where(diag > 1e-12 * max(float(diag.max(initial=0.0)), 1e-300),
                              residual / np.sqrt(np.maximum(diag, 1e-300)), np.nan)
    return Consistency(fit, SENSOR_AXES[s], chi2, dof, p_value, normalized, labels)


# -- the whole solve for many tables/sites at once (the Type B parts) -------------------------------

@dataclass
class _Pipeline:
    """The solve's linear operators, applied to closed-form outputs of erroneous tables."""

    imu: ImuCoefficients
    site: Site
    mounting: Any
    angles: np.ndarray | None                # (K, 3) positions
    p_acc: np.ndarray | None                 # (3, 4, K)
    w_bias: np.ndarray | None                # (3, K) gyro-bias weights (sum 1)
    turns: list[RotationObservation]
    p_rot: np.ndarray | None                 # (3, 4, K2)
    rate_dps: Any                            # deg/s: one, or one per turn

    def run(self, boxes: np.ndarray, site: Site | None = None) -> dict[str, np.ndarray]:
        """SI coefficients (R, ...) solved from exact outputs of tables `boxes` (R, 3, 3) at `site`."""
        site = site or self.site
        out: dict[str, np.ndarray] = {}
        if self.p_rot is not None:
            integral, _ = turn_integrals(self.turns, self.imu, site, self.rate_dps, boxes, self.mounting)
            gscale, gaxes, _ = scale_axes_bias(np.einsum("spk,rks->rsp", self.p_rot, integral))
            out["Kg"], out["Eg"] = gscale, gaxes
        else:
            gscale = np.broadcast_to(self.imu.gyro_scale, (len(boxes), 3))
            gaxes = np.broadcast_to(self.imu.gyro_axes, (len(boxes), 3, 3))
        if self.angles is not None:
            gyro_out, acc_out = position_outputs(self.angles, self.imu, site, boxes, self.mounting)
            if self.p_acc is not None:
                out["Ka"], out["Ea"], out["K0"] = scale_axes_bias(np.einsum("spk,rks->rsp", self.p_acc, acc_out))
            if self.w_bias is not None:
                _, w_nominal = nominal_position_inputs(self.angles, self.site, self.mounting)
                z = gyro_out / gscale[:, None, :] - np.einsum("kj,rsj->rks", w_nominal, gaxes)
                out["D0"] = np.einsum("sk,rks->rs", self.w_bias, z)
        return out


def _display(solved: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """(R,) display-unit values per canonical name."""
    out = {}
    for fam, value in solved.items():
        factor = RESULT_UNITS[fam][1]
        for i, s in enumerate(SENSOR_AXES):
            if fam in ("Ea", "Eg"):
                for j, a in enumerate(BODY_AXES):
                    out[f"{fam}_{a}{s}"] = value[:, i, j] / factor
            else:
                out[f"{fam}_{s}"] = value[:, i] / factor
    return out


def _table_draws(prior: TablePrior, draws: int, seed: int) -> np.ndarray:
    """(draws, 9) angles drawn from the prior (the same draws for coefficients and residuals)."""
    vals, vecs = np.linalg.eigh(prior.covariance_rad2)
    root = vecs * np.sqrt(np.maximum(vals, 0.0))                 # cov = root root^T
    return np.random.default_rng(seed).standard_normal((draws, 9)) @ root.T


def _probe_and_draw_boxes(angles: np.ndarray) -> np.ndarray:
    """Boxes: the ideal table, the 18 probes (+step, -step per angle), then the drawn tables."""
    return np.concatenate([np.zeros((1, 3, 3)), probe_boxes(_STEP_RAD), angles.reshape(-1, 3, 3)])


def _observation_table_part(outputs: np.ndarray, angles: np.ndarray, cov9: np.ndarray) -> np.ndarray:
    """(S, K, K) second moment of the observations' table error: first order `G Sigma G^T` plus
    the Monte-Carlo mean of the second-order rest's outer product; `outputs` (1 + 18 + R, K, S)
    over `_probe_and_draw_boxes`."""
    g = (outputs[1:10] - outputs[10:19]) / (2.0 * _STEP_RAD)              # (9, K, S)
    first = np.einsum("jks,ji,ils->skl", g, cov9, g)
    rest = outputs[19:] - outputs[0] - np.einsum("rj,jks->rks", angles, g)
    return first + np.einsum("rks,rls->skl", rest, rest) / len(angles)


def observation_table_covariance(imu: ImuCoefficients | None, position_angles_deg: np.ndarray, rotations,
                                 site: Site, inputs: BudgetInputs, mounting=None) -> dict[str, np.ndarray]:
    """The table's pointing error of the observations, (S, K, K) per kind: "gyro bias" and "accelerometers" (the
    position outputs, counts/s) and "gyros" (the turn integrals, counts); empty without a table prior."""
    obs_table: dict[str, np.ndarray] = {}
    if inputs.table is None or imu is None:
        return obs_table
    cov9 = inputs.table.covariance_rad2
    angles = _table_draws(inputs.table, inputs.mc_draws, inputs.seed)
    boxes = _probe_and_draw_boxes(angles)
    if len(position_angles_deg):
        gyro_out, acc_out = position_outputs(position_angles_deg, imu, site, boxes, mounting)
        obs_table["gyro bias"] = _observation_table_part(gyro_out, angles, cov9)
        obs_table["accelerometers"] = _observation_table_part(acc_out, angles, cov9)
    if rotations:
        integral, _ = turn_integrals(rotations, imu, site, inputs.rates_of(rotations), boxes, mounting)
        obs_table["gyros"] = _observation_table_part(integral, angles, cov9)
    return obs_table


def _table_part(pipe: _Pipeline, prior: TablePrior, draws: int, seed: int) -> dict[str, float]:
    """Per name: sqrt(first-order variance + mean square of the second-order rest)."""
    cov = prior.covariance_rad2
    angles = _table_draws(prior, draws, seed)
    values = _display(pipe.run(_probe_and_draw_boxes(angles)))
    out = {}
    for name, v in values.items():
        base = v[0]
        jac = (v[1:10] - v[10:19]) / (2.0 * _STEP_RAD)           # per rad
        first = float(jac @ cov @ jac)
        rest = v[19:] - base - angles @ jac
        out[name] = math.sqrt(max(first, 0.0) + float(np.mean(rest ** 2)))
    return out


def _site_part(pipe: _Pipeline, site: Site, inputs: BudgetInputs) -> dict[str, dict[str, float]]:
    zero = np.zeros((1, 3, 3))
    out: dict[str, dict[str, float]] = {}
    for comp, delta in ((GRAVITY, inputs.gravity_sigma_mps2), (LATITUDE, inputs.latitude_sigma_deg)):
        if not delta > 0:
            continue
        if comp == GRAVITY:
            sites = [Site(site.latitude_deg, site.height_m, site.gravity + d) for d in (delta, -delta)]
        else:
            lat = site.latitude_deg
            sites = [Site(min(90.0, lat + d), site.height_m, site.local_g) for d in (delta, -delta)]
        plus, minus = (_display(pipe.run(zero, s)) for s in sites)
        for name in plus:
            out.setdefault(name, {})[comp] = abs(float(plus[name][0] - minus[name][0])) / 2.0
    return out


# -- the budget ---------------------------------------------------------------------------------

def _labels(observations, prefix: str) -> list[str]:
    return [o.label or f"{prefix}{k + 1:02d}" for k, o in enumerate(observations)]


def compute_budget(acc: SensorTriad | None, gyros: SensorTriad | None, bias: GyroBias | None,
                   positions: list[PositionObservation], rotations: list[RotationObservation], site: Site,
                   inputs: BudgetInputs, mounting=None, gyro_prior: ImuCoefficients | None = None,
                   fitted_columns: dict[tuple[str, int], np.ndarray] | None = None) -> Budget:
    """The budget of a solve (`bench.solve.calibrate.solve`'s triads and gyro bias). `fitted_columns` ((fit,
    sensor) -> (K, m)): the columns an extended solve fitted and took off the observations before this solve; the
    residual tests project with them too (the residuals are the extended fit's, with its degrees of freedom)."""
    var: dict[str, dict[str, float]] = {}
    fitted = fitted_columns or {}

    def tested(fit: str, s: int, design: np.ndarray) -> np.ndarray:
        more = fitted.get((fit, s))
        return design if more is None or not more.size else np.column_stack([design, more])

    def add(name: str, comp: str, v: float) -> None:
        if v > 0 and math.isfinite(v):
            var.setdefault(name, {})[comp] = var.get(name, {}).get(comp, 0.0) + v

    def add_triad(scale: str, axes: str, bias_name: str | None, s: int, comp: str, v5: np.ndarray) -> None:
        f = RESULT_UNITS
        sensor = SENSOR_AXES[s]
        add(f"{scale}_{sensor}", comp, v5[0] / f[scale][1] ** 2)
        for j, a in enumerate(BODY_AXES):
            add(f"{axes}_{a}{sensor}", comp, v5[1 + j] / f[axes][1] ** 2)
        if bias_name:
            add(f"{bias_name}_{sensor}", comp, v5[4] / f[bias_name][1] ** 2)

    consistency: list[Consistency] = []
    flags: list[str] = []
    tau = inputs.correlation_time_s
    pos_angles = np.array([o.angles_deg for o in positions]) if positions else np.zeros((0, 3))
    imu = current_imu(acc, gyros, bias, gyro_prior)
    # the table's error of the observations (for the residual prediction): (S, K, K) per kind
    obs_table = observation_table_covariance(imu, pos_angles, rotations if gyros is not None else [], site, inputs,
                                             mounting)

    def table_cov(kind: str, s: int, scale: float = 1.0) -> np.ndarray | float:
        part = obs_table.get(kind)
        return 0.0 if part is None else part[s] / scale ** 2

    if acc is not None:
        design = position_design(pos_angles, site, mounting)
        starts, durations = _times(positions)
        kernel = gm_mean_kernel(starts, durations, tau)
        labels = _labels(positions, "P")
        for s in range(3):
            noise = acc.cov_noise_sensor(s)
            add_triad("Ka", "Ea", "K0", s, NOISE, np.diag(noise))
            c_gm = (acc.scale[s] * inputs.acc_bias_instability) ** 2 * kernel
            add_triad("Ka", "Ea", "K0", s, BIAS_INSTABILITY, _triad_var(acc, design, s, c_gm))
            acc_sigma = acc.fit.sigma
            if acc_sigma is not None:
                consistency.append(_consistency("accelerometers", s, tested("accelerometers", s, design),
                                                acc_sigma[:, s], acc.fit.residuals[:, s],
                                                np.diag(acc_sigma[:, s] ** 2) + c_gm + table_cov("accelerometers", s),
                                                labels))
    m_covs: dict[str, np.ndarray] = {}
    if gyros is not None:
        design = rotation_design(rotations, site, mounting)
        starts, durations = _times(rotations)
        kernel = gm_mean_kernel(starts, durations, tau) * np.outer(durations, durations)
        labels = _labels(rotations, "R")
        turned = np.array([o.sign * turn_axis_in_body(o.start_deg, o.frame_index, mounting=mounting)
                           for o in rotations])                 # (K, 3) d u_k: what an angle error turns
        angle_sigma = inputs.turn_angle_sigma_rad or 0.0
        for comp in (BIAS_INSTABILITY, RESOLUTION, TURN_ANGLE):     # the noise part is in the bias's own sigma_noise
            m_covs[comp] = np.zeros((3, 3, 3))
        for s in range(3):
            noise = gyros.cov_noise_sensor(s)
            add_triad("Kg", "Eg", None, s, NOISE, np.diag(noise))
            c_gm = (gyros.scale[s] * inputs.gyro_bias_instability) ** 2 * kernel
            c_q = _rounding_cov(rotations, s, inputs.count_resolution)
            c_turn = np.diag((turned @ gyros.fit.params[s][:3] * angle_sigma) ** 2)
            for comp, c_y in ((BIAS_INSTABILITY, c_gm), (RESOLUTION, c_q), (TURN_ANGLE, c_turn)):
                add_triad("Kg", "Eg", None, s, comp, _triad_var(gyros, design, s, c_y))
                p = _operator(design, None if gyros.fit.sigma is None else gyros.fit.sigma[:, s])
                m_covs[comp][s] = (p @ c_y @ p.T)[:3, :3]
            gyro_sigma = gyros.fit.sigma
            if gyro_sigma is not None:
                consistency.append(_consistency("gyros", s, tested("gyros", s, design), gyro_sigma[:, s],
                                                gyros.fit.residuals[:, s],
                                                np.diag(gyro_sigma[:, s] ** 2) + c_gm + c_q + c_turn
                                                + table_cov("gyros", s), labels))
        if inputs.turn_angle_sigma_rad is None:
            flags.append("uncertainty budget: the turns' angle error (the table's position repeatability at their "
                         "ends) is NOT included (set [table] turn_angle_error_arcsec)")
    w_bias = None
    if bias is not None:
        n = len(positions)
        starts, durations = _times(positions)
        kernel = gm_mean_kernel(starts, durations, tau)
        labels = _labels(positions, "P")
        sem = (pooled_sigma(np.array([o.standard_error("gyro") for o in positions]), durations)
               if bias.sigma_noise is not None else None)
        source = gyros if gyros is not None else gyro_prior
        assert source is not None, "a gyro bias is solved only with rotations or a prior"
        scale = source.scale if isinstance(source, SensorTriad) else source.gyro_scale
        dd_dm = bias.dd_dm if bias.dd_dm is not None else np.zeros((3, 3))
        w_bias = np.zeros((3, n))
        for s in range(3):
            sigma = None if sem is None or not np.all(sem[:, s] > 0) else sem[:, s] / scale[s]
            w = _operator(np.ones((n, 1)), sigma)[0]
            w_bias[s] = w
            if bias.sigma_noise is not None:
                add(f"D0_{SENSOR_AXES[s]}", NOISE, bias.sigma_noise[s] ** 2 / RESULT_UNITS["D0"][1] ** 2)
            c_gm = inputs.gyro_bias_instability ** 2 * kernel
            add(f"D0_{SENSOR_AXES[s]}", BIAS_INSTABILITY, float(w @ c_gm @ w) / RESULT_UNITS["D0"][1] ** 2)
            for comp, m_cov in m_covs.items():
                dd = dd_dm[s]
                add(f"D0_{SENSOR_AXES[s]}", comp, float(dd @ m_cov[s] @ dd) / RESULT_UNITS["D0"][1] ** 2)
            if sigma is not None:
                consistency.append(_consistency("gyro bias", s, tested("gyro bias", s, np.ones((n, 1))), sigma,
                                                bias.residuals[:, s],
                                                np.diag(sigma ** 2) + c_gm + table_cov("gyro bias", s, scale[s]),
                                                labels))
    # -- Type B parts through the whole solve
    if imu is not None:
        pipe = _Pipeline(imu, site, mounting, pos_angles if positions else None,
                         None if acc is None else np.stack([_operator(position_design(pos_angles, site, mounting),
                                                                      None if acc.fit.sigma is None
                                                                      else acc.fit.sigma[:, s]) for s in range(3)]),
                         w_bias, list(rotations),
                         None if gyros is None else np.stack([
                             _operator(rotation_design_nominal(rotations, site, inputs.rates_of(rotations), mounting),
                                       None if gyros.fit.sigma is None else gyros.fit.sigma[:, s]) for s in range(3)]),
                         inputs.rates_of(rotations))
        if inputs.table is not None:
            for name, sd in _table_part(pipe, inputs.table, inputs.mc_draws, inputs.seed).items():
                add(name, TABLE, sd * sd)
        for name, parts in _site_part(pipe, site, inputs).items():
            for comp, sd in parts.items():
                add(name, comp, sd * sd)
    else:
        flags.append("turntable and site parts of the budget not computed: too few coefficients solved")
    flags += _undithered_rounding(positions)
    if inputs.table is None:
        flags.append("uncertainty budget: the turntable's pointing error is NOT included (set [table] "
                     "pointing_accuracy_arcsec or [table] check): the uncertainties cover the IMU alone")
    # -- the fallback: scatter the budget does not explain
    fams = {"accelerometers": (("Ka", "Ea", "K0")), "gyros": ("Kg", "Eg"), "gyro bias": ("D0",)}
    for c in consistency:
        if c.consistent or not c.chi2 > c.dof:
            continue
        c.scale = math.sqrt(c.chi2 / c.dof)
        extra = c.chi2 / c.dof - 1.0
        for name in list(var):
            fam, axes = name.split("_", 1)
            if fam in fams[c.fit] and axes[-1] == c.sensor:
                random = var[name].get(NOISE, 0.0) + var[name].get(BIAS_INSTABILITY, 0.0)
                add(name, UNEXPLAINED, extra * random)
        flags.append(f"{c.describe()}: a wrong model, a moved IMU or a bad step? Uncertainties widened by "
                     f"{c.scale:.3g} as a fallback")
    components = {name: {comp: math.sqrt(v) for comp, v in parts.items()} for name, parts in var.items()}
    return Budget(components, consistency, inputs, flags)


#: the share of the rounding's step^2/12 left after averaging above which dwells round alike (sigma < ~0.3 step)
_UNDITHERED_SHARE = 0.01
_CHANNEL_NAMES = ("gyro x", "gyro y", "gyro z", "accelerometer x", "accelerometer y", "accelerometer z")


def _undithered_rounding(positions: list[PositionObservation]) -> list[str]:
    """A flag when an IMU that rounds each sample (sbg-ecan) has too little noise of its own to dither the
    rounding: its dwells' rounding errors then follow their signals (alike wherever the signals are), which the
    budget's per-dwell rounding part, taken as independent, does not cover."""
    stepped = [o for o in positions if o.output_step is not None and o.gyro_std is not None
               and o.acc_std is not None]
    if not stepped:
        return []
    step = np.asarray(stepped[0].output_step, dtype=float)
    std = np.sqrt(np.mean([np.concatenate([o.gyro_std, o.acc_std]) ** 2 for o in stepped], axis=0))
    share = rounding_bias_variance(std, step) / (step ** 2 / 12.0)
    undithered = [f"{name} {s:.0%}" for name, s in zip(_CHANNEL_NAMES, share) if s > _UNDITHERED_SHARE]
    if not undithered:
        return []
    return [f"uncertainty budget: the IMU's own noise does not dither its output resolution (the rounding left "
            f"after averaging: {', '.join(undithered)}): dwells with like signals round alike, which the "
            f"uncertainties do NOT cover"]


def _rounding_cov(rotations: list[RotationObservation], s: int, count_resolution: float) -> np.ndarray:
    """The turn integrals' output-resolution covariance for gyro `s` (counts^2): each turn's own rounding
    variance where the IMU rounds every sample (sbg-ecan), else the counter's, the same for every turn."""
    own = [o.rounding_var for o in rotations]
    if all(v is not None for v in own):
        return np.diag(np.array([float(v[s]) for v in own if v is not None]))
    return np.eye(len(rotations)) * _QUANT_VAR * count_resolution ** 2


def current_imu(acc, gyros, bias, gyro_prior) -> ImuCoefficients | None:
    """The solved coefficients as an `ImuCoefficients` (the point the Type B parts are linearised at)."""
    if acc is None and gyros is None:
        return None
    ref = gyro_prior
    if gyros is not None:
        g_scale, g_axes = gyros.scale, gyros.axes
    elif ref is not None:
        g_scale, g_axes = ref.gyro_scale, ref.gyro_axes
    else:
        g_scale, g_axes = np.full(3, 1e6), np.eye(3)
    g_bias = bias.value if bias is not None else np.zeros(3)
    if acc is not None:
        a_scale, a_axes, a_bias = acc.scale, acc.axes, acc.bias
    else:
        a_scale, a_axes, a_bias = np.full(3, 1e4), np.eye(3), np.zeros(3)
    return ImuCoefficients(g_scale, g_bias, g_axes, a_scale, a_bias, a_axes)


__all__ = ["BIAS_INSTABILITY", "COMMON_SOURCES", "GRAVITY", "K_EXPANDED", "LATITUDE", "NOISE", "RESOLUTION",
           "SOURCES", "TABLE", "TURN_ANGLE", "UNEXPLAINED", "Budget", "BudgetInputs", "Consistency", "TablePrior",
           "common_sigma", "compute_budget", "current_imu", "gm_mean_kernel", "observation_table_covariance"]
