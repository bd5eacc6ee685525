"""First-order sensitivity of solved coefficients to the nine black-box angles, and noise sigmas.

Sensitivity: d(solved coefficient)/d(black-box angle) at a zero black box, by exact
central differences through `bench.model.closed_form` and the solvers' own least squares
(the same path as `bench.schedule_design.monte_carlo`), in display units per arcsec. A schedule
"cancels" an angle for a coefficient when the derivative is below `ZERO_REL` of that
coefficient's natural scale (Earth rate for D0, g for K0, 1 for Ka, Kg, Ea, Eg).

Noise: 1-sigma of each coefficient from the least-squares covariance of the nominal
design, for white noise (ARW / VRW), first-order Gauss-Markov bias instability and
count quantisation (remainder carried, so the error of a sum is the difference of two
remainders) at the given dwell or turn time.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bench.model.closed_form import position_outputs, turn_integrals
from bench.model.earth import EARTH_RATE, Site
from bench.model.families import BODY_AXES, DESIGN_UNITS, POSITION_FAMILIES, ROTATION_FAMILIES, SENSOR_AXES, family_of
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.kinematics import FRAMES
from bench.model.units import ARCSEC, DEG, DEG_PER_HOUR, G0, MICRO_G
from bench.solve.budget import probe_boxes, rotation_design_nominal
from bench.solve.methods import (
    SolverError,
    nominal_position_inputs,
    position_design,
    scale_axes_bias,
    scale_axes_bias_jacobian,
)

#: The nine black-box angles: rows (outer = C_t^o0, middle = C_o^m0, inner = C_m^i0), columns.
ANGLE_NAMES = tuple(f"{row}.{col}" for row in FRAMES for col in ("alpha", "beta", "gamma"))
#: Index of the inner frame's zero offset (gamma of C_m^i0), which no schedule can see.
INNER_ZERO_OFFSET = ANGLE_NAMES.index("inner.gamma")
#: A derivative below this fraction of the coefficient's natural scale counts as cancelled.
ZERO_REL = 1e-7
STEP_RAD = 1.0 * ARCSEC   # central-difference step; third-order error ~ step^2, far below ZERO_REL

_OFF_DIAGONAL = [(s, a) for s in range(3) for a in range(3) if a != s]
#: Display unit of each family's sensitivity and noise, and SI -> display factor (per rad of angle).
_NATURAL_SI = {"D0": EARTH_RATE, "K0": G0, "Ka": 1.0, "Ea": 1.0, "Kg": 1.0, "Eg": 1.0}


def coefficient_names(families) -> tuple[str, ...]:
    """Canonical names of the coefficients a method solves at first order (no diagonal cosines:
    a unit vector's own component changes only at second order)."""
    names = []
    for fam in families:
        if fam in ("Ea", "Eg"):
            names += [f"{fam}_{BODY_AXES[a]}{SENSOR_AXES[s]}" for s, a in _OFF_DIAGONAL]
        else:
            names += [f"{fam}_{s}" for s in SENSOR_AXES]
    return tuple(names)


@dataclass(frozen=True)
class Sensitivity:
    """`matrix[c, j]`: d(coefficient c)/d(angle j) in `units[c]` per arcsec."""

    method: str                 # "positions" | "rotations"
    names: tuple[str, ...]
    units: tuple[str, ...]
    matrix: np.ndarray          # (C, 9)
    natural: np.ndarray         # (C,) natural scale per arcsec, display units
    #: Rotations only: the same with the Earth rate switched off, i.e. the pure geometry of
    #: the turns. Entries of `matrix` that vanish here are Earth-rate coupling (they shrink
    #: as T*Omega/(2 pi N), i.e. with faster turns), not a geometric error.
    geometric: np.ndarray | None = None

    @property
    def remaining(self) -> np.ndarray:
        """Boolean (C, 9): True where the angle is NOT cancelled at first order."""
        return np.abs(self.matrix) > ZERO_REL * self.natural[:, None]

    @property
    def remaining_geometric(self) -> np.ndarray:
        """Boolean (C, 9): remaining even without the Earth rate (all of `remaining` for positions)."""
        if self.geometric is None:
            return self.remaining
        return np.abs(self.geometric) > ZERO_REL * self.natural[:, None]

    def status(self) -> np.ndarray:
        """(C, 9) of '0' (cancelled), 'E' (Earth-rate coupling only) or 'R' (remains)."""
        out = np.full(self.matrix.shape, "0", dtype="<U1")
        out[self.remaining] = "E"
        out[self.remaining_geometric] = "R"
        return out

    def row(self, name: str) -> np.ndarray:
        return self.matrix[self.names.index(name)]

    def remaining_pairs(self) -> list[tuple[str, str]]:
        """(coefficient, angle) pairs that remain at first order."""
        rem = self.remaining
        return [(n, ANGLE_NAMES[j]) for i, n in enumerate(self.names) for j in range(9) if rem[i, j]]

    def families_remaining(self) -> dict[str, list[str]]:
        """Per family, the angles that remain in any of its coefficients."""
        out: dict[str, list[str]] = {}
        rem = self.remaining
        for fam in dict.fromkeys(family_of(n) for n in self.names):
            rows = [i for i, n in enumerate(self.names) if family_of(n) == fam]
            out[fam] = [ANGLE_NAMES[j] for j in range(9) if rem[rows, j].any()]
        return out


def solve_positions_batch(angles_deg, black_box_rad: np.ndarray, imu: ImuCoefficients,
                          site: Site, mounting=None) -> dict[str, np.ndarray]:
    """Position method on noise-free outputs for black boxes (R, 3, 3): SI coefficients per run, of an IMU mounted
    with `mounting` (`C_i^b`; None: the fixture's axes).

    The gyro bias uses the true Kg/Eg, as `bench.schedule_design.monte_carlo` does.
    """
    angles = np.asarray(angles_deg, dtype=float)
    design = position_design(angles, site, mounting)
    rank = np.linalg.matrix_rank(design, tol=1e-9 * np.abs(design).max())
    if rank < 4:
        raise SolverError(f"position schedule: the positions determine only {rank} of 4 unknowns per "
                          "accelerometer (need the specific force along all three body axes)")
    gyro_out, acc_out = position_outputs(angles, imu, site, black_box_rad, mounting)
    params = np.einsum("pk,rks->rsp", np.linalg.pinv(design), acc_out)
    scale, axes, bias = scale_axes_bias(params)
    _, w_nominal = nominal_position_inputs(angles, site, mounting)
    gyro_bias = (gyro_out / imu.gyro_scale - w_nominal @ imu.gyro_axes.T).mean(axis=1)
    return {"Ka": scale, "Ea": axes, "K0": bias, "D0": gyro_bias}


def solve_rotations_batch(turns, black_box_rad: np.ndarray, imu: ImuCoefficients, site: Site,
                          rate_dps: float = 10.0, mounting=None) -> dict[str, np.ndarray]:
    """Rotation method on noise-free integrals for black boxes (R, 3, 3): Kg, Eg per run (an IMU mounted with
    `mounting`)."""
    design = rotation_design_nominal(turns, site, rate_dps, mounting)
    rank = np.linalg.matrix_rank(design, tol=1e-9 * np.abs(design).max())
    if rank < 4:
        raise SolverError(f"rotation schedule: the turns determine only {rank} of 4 unknowns per gyro "
                          "(need turns about all three body axes in both senses)")
    integral, _ = turn_integrals(turns, imu, site, rate_dps, black_box_rad, mounting)
    params = np.einsum("pk,rks->rsp", np.linalg.pinv(design), integral)
    scale, axes, _ = scale_axes_bias(params)
    return {"Kg": scale, "Eg": axes}


def _to_rows(solved: dict[str, np.ndarray], imu: ImuCoefficients, families) -> np.ndarray:
    """(R, C) coefficient values in display units (scale factors relative, as ppm of truth)."""
    cols = []
    for fam in families:
        factor = DESIGN_UNITS[fam][1]
        value = solved[fam]
        if fam in ("Ea", "Eg"):
            cols += [value[:, s, a] * factor for s, a in _OFF_DIAGONAL]
        elif fam in ("Ka", "Kg"):
            truth = imu.acc_scale if fam == "Ka" else imu.gyro_scale
            cols += [(value[:, s] / truth[s] - 1.0) * factor for s in range(3)]
        else:
            cols += [value[:, s] * factor for s in range(3)]
    return np.stack(cols, axis=1)


def _difference(solved, imu: ImuCoefficients, families, step_rad: float) -> np.ndarray:
    rows = _to_rows(solved, imu, families)
    return (rows[:9] - rows[9:]).T / (2.0 * step_rad / ARCSEC)


@dataclass(frozen=True)
class _NoEarthSite(Site):
    """A site whose Earth rate is zero: isolates the geometric part of a turn's sensitivity."""

    @classmethod
    def of(cls, site: Site) -> _NoEarthSite:
        return cls(site.latitude_deg, site.height_m, site.local_g)

    @property
    def earth_rate_enu(self) -> np.ndarray:
        return np.zeros(3)


def _sensitivity(method: str, families, solved, imu: ImuCoefficients, step_rad: float,
                 geometric: np.ndarray | None = None) -> Sensitivity:
    matrix = _difference(solved, imu, families, step_rad)
    names = coefficient_names(families)
    fams = [family_of(n) for n in names]
    units = tuple(DESIGN_UNITS[f][0] for f in fams)
    natural = np.array([_NATURAL_SI[f] * DESIGN_UNITS[f][1] * ARCSEC for f in fams])
    return Sensitivity(method, names, units, matrix, natural, geometric)


def position_sensitivity(angles_deg, imu: ImuCoefficients | None = None, site: Site | None = None,
                         step_rad: float = STEP_RAD, mounting=None) -> Sensitivity:
    """First-order sensitivity of D0 (with true Kg/Eg), K0, Ka, Ea to the nine angles (an IMU mounted with
    `mounting`: its own coefficients)."""
    imu = imu or default_sim_imu()
    site = site or Site()
    solved = solve_positions_batch(angles_deg, probe_boxes(step_rad), imu, site, mounting)
    return _sensitivity("positions", POSITION_FAMILIES, solved, imu, step_rad)


def rotation_sensitivity(turns, imu: ImuCoefficients | None = None, site: Site | None = None,
                         rate_dps: float = 10.0, step_rad: float = STEP_RAD, mounting=None) -> Sensitivity:
    """First-order sensitivity of Kg, Eg to the nine angles (an IMU mounted with `mounting`)."""
    imu = imu or default_sim_imu()
    site = site or Site()
    boxes = probe_boxes(step_rad)
    solved = solve_rotations_batch(turns, boxes, imu, site, rate_dps, mounting)
    no_earth = solve_rotations_batch(turns, boxes, imu, _NoEarthSite.of(site), rate_dps, mounting)
    geometric = _difference(no_earth, imu, ROTATION_FAMILIES, step_rad)
    return _sensitivity("rotations", ROTATION_FAMILIES, solved, imu, step_rad, geometric)


# --- noise ------------------------------------------------------------------------

def _gm_mean_var(sigma: float, tau_s: float, t_s: float) -> float:
    """Variance of the time average over t_s of a first-order Gauss-Markov process."""
    if sigma == 0.0 or t_s <= 0.0:
        return 0.0
    x = t_s / tau_s
    return sigma ** 2 * 2.0 / x ** 2 * (x - 1.0 + math.exp(-x))


_QUANT_COUNTS = 1.0 / math.sqrt(6.0)  # std of the difference of two uniform remainders


def position_noise_sigma(angles_deg, noise: NoiseModel, dwell_s: float, imu: ImuCoefficients | None = None,
                         site: Site | None = None, mounting=None) -> dict[str, float]:
    """1-sigma of each position-method coefficient (display units; Ka in ppm, Ea in arcsec) of an IMU mounted
    with `mounting` (its own axes)."""
    imu = imu or default_sim_imu()
    site = site or Site()
    if dwell_s <= 0:
        raise ValueError(f"dwell_s must be positive, got {dwell_s}")
    design = position_design(np.asarray(angles_deg, dtype=float), site, mounting)
    try:
        inv = np.linalg.inv(design.T @ design)
    except np.linalg.LinAlgError as exc:
        raise SolverError("position schedule: singular design") from exc
    tau = noise.correlation_time_s
    out: dict[str, float] = {}
    acc_white = noise.acc_vrw_ug_rt_hz * MICRO_G / math.sqrt(dwell_s)
    acc_gm = _gm_mean_var(noise.acc_bias_instability_ug * MICRO_G, tau, dwell_s)
    for s in range(3):
        quant = (_QUANT_COUNTS / dwell_s / imu.acc_scale[s]) if noise.quantise else 0.0
        sigma_counts = imu.acc_scale[s] * math.sqrt(acc_white ** 2 + acc_gm + quant ** 2)
        params = np.concatenate([imu.acc_matrix[s], [imu.acc_scale[s] * imu.acc_bias[s]]])
        jac = scale_axes_bias_jacobian(params)
        cov = jac @ (sigma_counts ** 2 * inv) @ jac.T
        sd = np.sqrt(np.diag(cov))
        out[f"Ka_{SENSOR_AXES[s]}"] = sd[0] / imu.acc_scale[s] * DESIGN_UNITS["Ka"][1]
        out[f"K0_{SENSOR_AXES[s]}"] = sd[4] * DESIGN_UNITS["K0"][1]
        for a in range(3):
            if a != s:
                out[f"Ea_{BODY_AXES[a]}{SENSOR_AXES[s]}"] = sd[1 + a] * DESIGN_UNITS["Ea"][1]
    gyro_white = noise.gyro_arw_deg_rt_h * DEG / 60.0 / math.sqrt(dwell_s)
    gyro_gm = _gm_mean_var(noise.gyro_bias_instability_dph * DEG_PER_HOUR, tau, dwell_s)
    k = len(design)
    for s in range(3):
        quant = (_QUANT_COUNTS / dwell_s / imu.gyro_scale[s]) if noise.quantise else 0.0
        out[f"D0_{SENSOR_AXES[s]}"] = math.sqrt((gyro_white ** 2 + gyro_gm + quant ** 2) / k) * DESIGN_UNITS["D0"][1]
    return {n: out[n] for n in coefficient_names(POSITION_FAMILIES)}


def rotation_noise_sigma(turns, noise: NoiseModel, rate_dps: float = 10.0, imu: ImuCoefficients | None = None,
                         site: Site | None = None, mounting=None) -> dict[str, float]:
    """1-sigma of Kg (ppm) and Eg (arcsec) from each turn's integrated gyro noise (an IMU mounted with
    `mounting`)."""
    imu = imu or default_sim_imu()
    site = site or Site()
    design = rotation_design_nominal(turns, site, rate_dps, mounting)
    durations = design[:, 3]
    arw = noise.gyro_arw_deg_rt_h * DEG / 60.0            # rad/sqrt(s)
    bi = noise.gyro_bias_instability_dph * DEG_PER_HOUR
    # Integral noise per turn (rad): white ARW*sqrt(T) and the GM bias integrated over T.
    var_rad = np.array([arw ** 2 * t + t ** 2 * _gm_mean_var(bi, noise.correlation_time_s, t) for t in durations])
    out: dict[str, float] = {}
    for s in range(3):
        quant = _QUANT_COUNTS if noise.quantise else 0.0
        sigma = np.sqrt(imu.gyro_scale[s] ** 2 * var_rad + quant ** 2)
        aw = design / sigma[:, None]
        try:
            cov0 = np.linalg.inv(aw.T @ aw)
        except np.linalg.LinAlgError as exc:
            raise SolverError("rotation schedule: singular design") from exc
        params = np.concatenate([imu.gyro_matrix[s], [imu.gyro_scale[s] * imu.gyro_bias[s]]])
        jac = scale_axes_bias_jacobian(params)
        sd = np.sqrt(np.diag(jac @ cov0 @ jac.T))
        out[f"Kg_{SENSOR_AXES[s]}"] = sd[0] / imu.gyro_scale[s] * DESIGN_UNITS["Kg"][1]
        for a in range(3):
            if a != s:
                out[f"Eg_{BODY_AXES[a]}{SENSOR_AXES[s]}"] = sd[1 + a] * DESIGN_UNITS["Eg"][1]
    return {n: out[n] for n in coefficient_names(ROTATION_FAMILIES)}


# --- black-box prediction of a schedule (a task of `bench schedules recommend`) -----------------

def _family_rows(names: tuple[str, ...], fam: str) -> list[int]:
    return [i for i, n in enumerate(names) if family_of(n) == fam]


def first_order(sens: Sensitivity, level_arcsec: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
    """Per family: RSS of sensitivity x level without the inner zero offset, and that offset's part alone."""
    contrib = sens.matrix * level_arcsec.ravel()[None, :]
    reducible, irreducible = {}, {}
    for fam in dict.fromkeys(family_of(n) for n in sens.names):
        rows = contrib[_family_rows(sens.names, fam)]
        irreducible[fam] = float(np.sqrt(np.sum(rows[:, INNER_ZERO_OFFSET] ** 2)))
        reducible[fam] = float(np.sqrt(np.sum(np.delete(rows, INNER_ZERO_OFFSET, axis=1) ** 2)))
    return reducible, irreducible


def _display_rows(solved: dict[str, np.ndarray], names: tuple[str, ...], imu: ImuCoefficients) -> np.ndarray:
    """(R, C) solved coefficients in display units, in `names` order (scale factors as ppm of truth)."""
    cols = []
    for name in names:
        fam, suffix = name.split("_", 1)
        factor = DESIGN_UNITS[fam][1]
        if fam in ("Ea", "Eg"):
            cols.append(solved[fam][:, SENSOR_AXES.index(suffix[1]), BODY_AXES.index(suffix[0])] * factor)
        elif fam in ("Ka", "Kg"):
            truth = imu.acc_scale if fam == "Ka" else imu.gyro_scale
            s = SENSOR_AXES.index(suffix)
            cols.append((solved[fam][:, s] / truth[s] - 1.0) * factor)
        else:
            cols.append(solved[fam][:, SENSOR_AXES.index(suffix)] * factor)
    return np.stack(cols, axis=1)


def second_order(solve, sens: Sensitivity, unit_draws: np.ndarray, level_arcsec: np.ndarray,
                  imu: ImuCoefficients) -> dict[str, float]:
    """RMS over draws of (exact solve - zero-box solve - first-order prediction), RSS per family."""
    angles_arcsec = unit_draws * level_arcsec[None]                             # (R, 3, 3)
    boxes = np.concatenate([np.zeros((1, 3, 3)), angles_arcsec * ARCSEC])
    rows = _display_rows(solve(boxes), sens.names, imu)
    linear = angles_arcsec.reshape(len(unit_draws), 9) @ sens.matrix.T
    residual = rows[1:] - rows[:1] - linear
    out = {}
    for fam in dict.fromkeys(family_of(n) for n in sens.names):
        per_run = np.sum(residual[:, _family_rows(sens.names, fam)] ** 2, axis=1)
        out[fam] = float(np.sqrt(np.mean(per_run))) if len(per_run) else 0.0
    return out


def predict_black_box(angles_deg: np.ndarray | None, turns: list | None, imu: ImuCoefficients, site: Site,
                      unit_draws: np.ndarray, level_arcsec: np.ndarray, turn_rate_dps: float = 0.0
                      ) -> tuple[dict[str, float], dict[str, float], dict[str, float]]:
    """One task: a position schedule's (`angles_deg`) or a rotation schedule's (`turns`) black-box error per family:
    first order, second order (the Monte Carlo over `unit_draws`) and the irreducible part. Raises SolverError."""
    if angles_deg is not None:
        sens = position_sensitivity(angles_deg, imu, site)
        second = second_order(lambda b: solve_positions_batch(angles_deg, b, imu, site), sens, unit_draws,
                               level_arcsec, imu)
    else:
        sens = rotation_sensitivity(turns, imu, site, turn_rate_dps)
        second = second_order(lambda b: solve_rotations_batch(turns, b, imu, site, turn_rate_dps), sens,
                               unit_draws, level_arcsec, imu)
    first, irreducible = first_order(sens, level_arcsec)
    return first, second, irreducible


__all__ = ["ANGLE_NAMES", "INNER_ZERO_OFFSET", "STEP_RAD", "ZERO_REL", "Sensitivity", "coefficient_names",
           "first_order", "position_noise_sigma", "position_sensitivity", "predict_black_box",
           "rotation_design_nominal", "rotation_noise_sigma", "rotation_sensitivity", "second_order",
           "solve_positions_batch", "solve_rotations_batch"]
