"""Monte-Carlo evaluation of schedules against turntable pointing error (paper Tables 2, 4).

Noise-free world whose only error is the black box: nine angles drawn normal with the
level as their RMS. Per run, each coefficient family's error is the root-sum-square
over its axes (direction cosines: over all nine); over runs, the RMS. Vectorised over
runs: the design matrix is nominal, hence the same for every run.

Position tables solve the gyro bias with the true Kg/Eg, so that they show the position
method's own error, as the paper separates the two methods.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bench.model.closed_form import position_outputs, turn_closed_form, turn_integrals
from bench.model.earth import Site
from bench.model.families import POSITION_KEYS, ROTATION_KEYS
from bench.model.imu import ImuCoefficients, default_sim_imu
from bench.model.units import ARCSEC, DEG_PER_HOUR, G0
from bench.parallel import run_tasks
from bench.solve.methods import nominal_position_inputs, position_design, scale_axes_bias
from schedules import RotationStep, load_builtin

POSITION_LEVELS_ARCSEC = (26.7, 85.0, 275.5)
ROTATION_LEVELS_ARCSEC = (27.8, 83.1, 273.1)
POSITION_SCHEDULES = {"optimal": "optimal-24", "traditional": "traditional-12"}
ROTATION_SCHEDULES = {"optimal": "optimal-5s6r", "traditional": "traditional-3s6r"}

#: The paper's Table 2 (level, method) -> (gyro bias deg/h, acc bias g, acc SF, acc axes).
PAPER_POSITIONS = {
    (26.7, "optimal"): (1.20e-7, 1.58e-8, 1.00e-7, 1.80e-4),
    (26.7, "traditional"): (1.02e-3, 2.03e-4, 4.50e-7, 3.51e-4),
    (85.0, "optimal"): (1.13e-6, 1.49e-7, 7.80e-7, 5.61e-4),
    (85.0, "traditional"): (2.68e-3, 5.31e-4, 1.30e-6, 7.13e-4),
    (275.5, "optimal"): (1.38e-5, 1.83e-6, 5.24e-6, 1.89e-3),
    (275.5, "traditional"): (9.11e-3, 1.80e-3, 1.06e-5, 3.54e-3),
}
#: The paper's Table 4 (level, method) -> (gyro SF, gyro axes).
PAPER_ROTATIONS = {
    (27.8, "optimal"): (5.00e-8, 1.89e-4),
    (27.8, "traditional"): (2.80e-7, 5.08e-4),
    (83.1, "optimal"): (3.20e-7, 5.73e-4),
    (83.1, "traditional"): (1.10e-6, 1.23e-3),
    (273.1, "optimal"): (1.42e-6, 1.90e-3),
    (273.1, "traditional"): (6.61e-6, 4.57e-3),
}
#: Monte-Carlo runs per task: fixed, not from the number of workers, so that the sums (and the tables) are the
#: same however the tasks are scheduled; about 0.5 s of work on the development machine
CHUNK_RUNS = 2000


def draw_black_boxes(runs: int, seed: int) -> np.ndarray:
    """Standard-normal black-box angles (runs, 3, 3); multiply by the level (rad)."""
    return np.random.default_rng(seed).standard_normal((runs, 3, 3))


def _rss(x: np.ndarray, axes: tuple[int, ...]) -> np.ndarray:
    return np.sqrt(np.sum(x * x, axis=axes))


def position_errors(angles_deg: np.ndarray, black_box_rad: np.ndarray, imu: ImuCoefficients,
                    site: Site) -> dict[str, np.ndarray]:
    """Per-run RSS errors of the position method for black boxes (runs, 3, 3)."""
    angles = np.asarray(angles_deg, dtype=float)
    gyro_out, acc_out = position_outputs(angles, imu, site, black_box_rad)              # (R, K, 3)
    design = position_design(angles, site)
    params = np.einsum("pk,rks->rsp", np.linalg.pinv(design), acc_out)                 # (R, 3, 4)
    scale, axes, bias = scale_axes_bias(params)
    _, w_nominal = nominal_position_inputs(angles, site)                               # (K, 3)
    gyro_bias = (gyro_out / imu.gyro_scale - w_nominal @ imu.gyro_axes.T).mean(axis=1)
    return {
        "gyro_bias_dph": _rss((gyro_bias - imu.gyro_bias) / DEG_PER_HOUR, (1,)),
        "acc_bias_g": _rss((bias - imu.acc_bias) / G0, (1,)),
        "acc_scale": _rss(scale / imu.acc_scale - 1.0, (1,)),
        "acc_axes": _rss(axes - imu.acc_axes, (1, 2)),
    }


def rotation_errors(turns: list[RotationStep], black_box_rad: np.ndarray, imu: ImuCoefficients, site: Site,
                    rate_dps: float = 10.0) -> dict[str, np.ndarray]:
    """Per-run RSS errors of the rotation method for black boxes (runs, 3, 3)."""
    integral, durations = turn_integrals(turns, imu, site, rate_dps, black_box_rad)
    rot_nom, earth_nom, _ = turn_closed_form(turns, site, rate_dps)
    design = np.column_stack([rot_nom + earth_nom, durations])
    params = np.einsum("pk,rks->rsp", np.linalg.pinv(design), integral)
    scale, axes, _ = scale_axes_bias(params)
    return {
        "gyro_scale": _rss(scale / imu.gyro_scale - 1.0, (1,)),
        "gyro_axes": _rss(axes - imu.gyro_axes, (1, 2)),
    }


def _chunk_sums(unit: np.ndarray, position_schedules: dict[str, np.ndarray],
                rotation_schedules: dict[str, list[RotationStep]], imu: ImuCoefficients, site: Site,
                position_levels, rotation_levels, rate_dps: float) -> dict[tuple, dict[str, float]]:
    """One task: per (table, level, method), the sum over this chunk's runs of each squared per-run error."""
    out: dict[tuple, dict[str, float]] = {}
    for level in position_levels:
        for method, angles in position_schedules.items():
            errs = position_errors(angles, unit * level * ARCSEC, imu, site)
            out[("positions", level, method)] = {k: float(np.sum(errs[k] * errs[k])) for k in POSITION_KEYS}
    for level in rotation_levels:
        for method, turns in rotation_schedules.items():
            errs = rotation_errors(turns, unit * level * ARCSEC, imu, site, rate_dps)
            out[("rotations", level, method)] = {k: float(np.sum(errs[k] * errs[k])) for k in ROTATION_KEYS}
    return out


def chunk_sizes(runs: int, chunk_runs: int = CHUNK_RUNS) -> list[int]:
    """The runs of each task: `chunk_runs` each, the last one the rest."""
    return [min(chunk_runs, runs - start) for start in range(0, runs, chunk_runs)]


def evaluate(position_schedules: dict[str, np.ndarray], rotation_schedules: dict[str, list[RotationStep]],
             runs: int = 100, seed: int = 0, imu: ImuCoefficients | None = None, site: Site | None = None,
             position_levels=POSITION_LEVELS_ARCSEC, rotation_levels=ROTATION_LEVELS_ARCSEC,
             rate_dps: float = 10.0, *, scheduler: str = "loop", workers: int | None = None,
             progress: Callable[[int, int], None] | None = None, chunk_runs: int = CHUNK_RUNS
             ) -> dict[str, list[dict]]:
    """RMS over runs of each error, per level and method, in the JSON shape of `bench evaluate`.

    The same standard-normal draws, scaled to each level, serve every method and level,
    so differences between cells are the schedules', not the dice's. The runs go in
    chunks of `chunk_runs`, each a task of `bench.parallel.run_tasks` on `scheduler` with
    its draws (the next ones of the one generator of `seed`, drawn here in order), and
    the chunks' sums of squares are added in chunk order: the tables are the same to the
    last bit on any scheduler and number of workers. `progress(done, total)` after each chunk.
    """
    imu = imu or default_sim_imu()
    site = site or Site()
    rng = np.random.default_rng(seed)
    sizes = chunk_sizes(runs, chunk_runs)
    calls = ((rng.standard_normal((n, 3, 3)), position_schedules, rotation_schedules, imu, site,
              tuple(position_levels), tuple(rotation_levels), rate_dps) for n in sizes)
    sums: list[dict[tuple, dict[str, float]] | None] = [None] * len(sizes)
    for done, (index, result, error) in enumerate(run_tasks(_chunk_sums, calls, scheduler=scheduler,
                                                            workers=workers), 1):
        if error is not None:
            raise error
        sums[index] = result
        if progress is not None:
            progress(done, len(sizes))
    out: dict[str, list[dict]] = {"positions": [], "rotations": []}
    for table, level, method in sums[0] or {}:
        keys = POSITION_KEYS if table == "positions" else ROTATION_KEYS
        totals = {k: 0.0 for k in keys}
        for chunk in sums:
            for k in keys:
                totals[k] += chunk[(table, level, method)][k]      # type: ignore[index]
        out[table].append({"level_arcsec": level, "method": method,
                           **{k: math.sqrt(totals[k] / runs) for k in keys}})
    return out


def paper_value(table: str, level: float, method: str, key: str) -> float | None:
    """The paper's value for a cell, or None when the paper has no such cell."""
    if table == "positions":
        row = PAPER_POSITIONS.get((level, method))
        return None if row is None else row[POSITION_KEYS.index(key)]
    rotation_row = PAPER_ROTATIONS.get((level, method))
    return None if rotation_row is None else rotation_row[ROTATION_KEYS.index(key)]


def builtin_schedules() -> tuple[dict[str, np.ndarray], dict[str, list[RotationStep]]]:
    """The paper's optimal and traditional schedules, loaded from the shipped files."""
    positions = {m: np.array([p.angles_deg for p in load_builtin(n).positions]) for m, n in POSITION_SCHEDULES.items()}
    rotations = {m: list(load_builtin(n).rotations) for m, n in ROTATION_SCHEDULES.items()}
    return positions, rotations
