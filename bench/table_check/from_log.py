"""The table check from a run log: the one path shared by a live/simulated check (its own log) and `--log`.

The log is the source of truth: per-position means come from the recorded CAN frames
(`bench.solve.from_logs.extract_from_logs`), the site and, for a simulated run, the true
black box from the recorded configuration (`bench.log.run_info`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bench import __version__
from bench.log.names import run_id_of
from bench.log.reader import LogError, read_log
from bench.log.run_info import layout_and_config_from_log
from bench.model.quality import texts
from bench.model.table_prior import CHECK_FORMAT
from bench.model.units import ARCSEC, MICRO_G
from bench.solve.from_logs import extract_from_logs
from bench.solve.inputs import DEFAULT_CORRELATION_TIME_S, bias_stabilities, correlation_time_s
from bench.table_check.estimate import (
    COMBINATIONS,
    NOMINAL_RELATIVE_UNCERTAINTY,
    Conversion,
    TableCheckError,
    TableCheckEstimate,
    conversion_error,
    estimate,
    horizontal_from_counts,
    true_combinations,
)

FORMAT = CHECK_FORMAT
VERSION = 1


@dataclass
class TableCheckAnalysis:
    """A table check's estimate with its provenance and, for a simulated run, the truth."""

    run_id: str
    log_path: str
    mode: str                                   # "simulator" | "hardware" | "" (unknown)
    estimate: TableCheckEstimate
    conversion: Conversion
    labels: list[str]
    dwell_s: float
    site: dict
    imu: dict
    black_box_rad: np.ndarray | None = None     # the simulated table's black box (truth), None on hardware
    operator: str = ""                          # who ran the check (the log's run record)
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    @property
    def truth_rad(self) -> np.ndarray | None:
        return None if self.black_box_rad is None else true_combinations(self.black_box_rad)

    def comparison(self) -> list[dict] | None:
        truth = self.truth_rad
        return None if truth is None else self.estimate.compare(truth)

    @property
    def sim_within_3_sigma(self) -> bool | None:
        rows = self.comparison()
        return None if rows is None else all(r["within_3_sigma"] for r in rows)

    def to_json(self) -> dict:
        est = self.estimate
        out = {
            "format": FORMAT, "version": VERSION, "software_version": __version__,
            "run": {"run_id": self.run_id, "log": Path(self.log_path).name, "mode": self.mode,
                    "operator": self.operator,
                    "positions": len(self.labels), "dwell_s": self.dwell_s, "site": self.site, "imu": self.imu},
            "conversion": {"scale_counts_per_g": [float(s) for s in self.conversion.scale_counts_per_g],
                           "source": self.conversion.source, "calibrated": self.conversion.calibrated,
                           "relative_uncertainty": self.conversion.relative_uncertainty},
            **est.to_dict(),
            "per_position": [{"label": label, "angles_deg": [float(x) for x in a],
                              "horizontal_g": [float(x) for x in y], "sigma_g": [float(x) for x in s],
                              "residual_g": [float(x) for x in r]}
                             for label, a, y, s, r in zip(self.labels, est.angles_deg, est.horizontal_g,
                                                          est.sigma_g, est.residual_g)],
            "problems": list(self.problems), "notes": list(self.notes),
        }
        truth = self.truth_rad
        if truth is not None:       # a simulated run: its black box is known
            out["sim_truth"] = {
                "black_box_arcsec": (np.asarray(self.black_box_rad) / ARCSEC).tolist(),
                "combinations_arcsec": {c.key: float(t) for c, t in zip(COMBINATIONS, truth / ARCSEC)},
                "comparison": self.comparison(), "all_within_3_sigma": self.sim_within_3_sigma}
        return out


def table_check_observations(extraction, log_path: str) -> list:
    """The dwells of a table-check log; TableCheckError when the log is not a table check."""
    positions, rotations = extraction.positions, extraction.rotations
    off = [o for o in positions if abs((o.angles_deg[1] + 180.0) % 360.0 - 180.0) > 1e-6]
    if rotations or off or not positions:
        what = (f"{len(positions)} positions ({len(off)} with the middle frame off 0) and {len(rotations)} rotations"
                if positions or rotations else "no finished positions")
        raise TableCheckError(f"{log_path} is not a table-check log: it holds {what}; a table check has positions "
                              "with the middle frame at 0 only (record one with `bench check-table`)")
    return positions


def analyse_observations(observations, local_g_mps2: float, *, calibration=None, acc_drift_ug: float = 0.0,
                         correlation_time_s: float = DEFAULT_CORRELATION_TIME_S,
                         relative_uncertainty: float = NOMINAL_RELATIVE_UNCERTAINTY,
                         ) -> tuple[TableCheckEstimate, Conversion]:
    """Estimate from position observations (counts/s means with standard errors).

    The dwells are weighted by the pooled residual scatter of each axis (scaled by
    sqrt(median dwell / dwell)), not by their own standard errors: the block-mean scatter
    of a quantised output depends on the signal itself (its fractional counts), so weights
    from it correlate with the errors and bias the estimate (at 2 s dwells by about 1.4
    sigma RMS). `acc_drift_ug`: the accelerometers' bias instability (1-sigma of a
    Gauss-Markov bias of `correlation_time_s`), which correlates the dwells by their times
    (`estimate`'s drift). `relative_uncertainty`: the uncalibrated x/y accelerometers' error
    against z (`horizontal_from_counts`).
    """
    angles = np.array([o.angles_deg for o in observations], dtype=float)
    acc = np.array([o.acc_mean for o in observations], dtype=float)
    sem = np.array([_sem(o) for o in observations], dtype=float)
    horizontal, sem_g, conversion = horizontal_from_counts(acc, sem, local_g_mps2, calibration=calibration,
                                                           relative_uncertainty=relative_uncertainty)
    durations = np.array([o.duration_s for o in observations], dtype=float)
    first = estimate(angles, horizontal, None, with_observability=False)
    dof_per_axis = max(len(angles) - 3, 1)
    pooled = np.sqrt(np.sum(first.residual_g ** 2, axis=0) / dof_per_axis)        # (2,) at the median dwell
    sigma = pooled[None, :] * np.sqrt(np.median(durations) / durations)[:, None]
    if not np.all(sigma > 0):
        sigma = None        # an exact fit (noise-free outputs): the residual scatter sets the uncertainty
    starts = [o.start_s for o in observations]
    est = estimate(angles, horizontal, sigma, relative_scale_uncertainty=conversion.relative_uncertainty,
                   drift_g=acc_drift_ug * MICRO_G / local_g_mps2,
                   start_s=None if any(t is None for t in starts) else starts, duration_s=durations,
                   correlation_time_s=correlation_time_s)
    est.notes.append("dwells weighted by the pooled residual scatter of each axis"
                     + (f"; accelerometer bias drift {acc_drift_ug:g} ug (correlation time {correlation_time_s:g} s) "
                        "modelled" if acc_drift_ug > 0 and sigma is not None else ""))
    return est, conversion


def conversion_uncertainty(config, sim: bool, local_g_mps2: float) -> float:
    """The uncalibrated x/y accelerometers' relative error against z (`horizontal_from_counts`):
    `[imu.identity] acc_xy_to_z_uncertainty`; on the simulator without it the simulated IMU's own
    (`conversion_error`: what its datasheet would say); else `NOMINAL_RELATIVE_UNCERTAINTY`."""
    configured = config.imu.identity.acc_xy_to_z_uncertainty
    if configured is not None:
        return configured
    return conversion_error(config.sim.imu, local_g_mps2)[2] if sim else NOMINAL_RELATIVE_UNCERTAINTY


def _sem(o) -> np.ndarray:
    s = o.standard_error("acc")
    return np.full(3, math.nan) if s is None else s


def analyse_log(path: str | Path, *, calibration=None, still_open: bool = False) -> TableCheckAnalysis:
    """Read a table-check log and estimate the table's pointing error.

    Raises `LogError` (not a readable log) or `TableCheckError` (not a table check, or
    the positions cannot determine the combinations). `still_open`: the live check
    reading the log it is still writing (its missing summary is not damage).
    """
    log = read_log(str(path))
    setup = layout_and_config_from_log(log)
    if setup.site is None:
        raise LogError(f"{log.path}: the log records no usable site ({'; '.join(setup.notes)})")
    extraction, stats, damage = extract_from_logs([log], setup.site, setup.layout, setup.rate_hz,
                                                  still_open=frozenset({log.path}) if still_open else frozenset())
    observations = table_check_observations(extraction, log.path)
    run_meta = log.metadata.get("run", {})
    mode = run_meta.get("mode", "")
    drift_ug, tau, eps = 0.0, DEFAULT_CORRELATION_TIME_S, NOMINAL_RELATIVE_UNCERTAINTY
    if setup.config is not None:
        sim = mode == "simulator"
        drift_ug = bias_stabilities(setup.config, sim)[1] or 0.0
        tau = correlation_time_s(setup.config, sim)
        eps = conversion_uncertainty(setup.config, sim, setup.site.gravity)
    est, conversion = analyse_observations(observations, setup.site.gravity, calibration=calibration,
                                           acc_drift_ug=drift_ug, correlation_time_s=tau, relative_uncertainty=eps)
    black_box = None
    if mode == "simulator" and setup.config is not None:
        black_box = np.asarray(setup.config.sim.black_box_rad, dtype=float)
    problems = texts(extraction.problems) + list(damage)
    if stats and stats[0].lost_samples:
        problems.append(f"IMU link lost samples: {stats[0].summary()}")
    imu_meta = log.metadata.get("imu", {})
    dwell = float(np.median([o.duration_s for o in observations]))
    run_id, renamed = run_id_of(log.path, log.metadata)      # names the output files: a safe name only
    return TableCheckAnalysis(
        run_id=run_id, log_path=log.path, mode=mode, estimate=est,
        conversion=conversion, labels=[o.label for o in observations], dwell_s=dwell,
        site=setup.site.to_dict(), imu={"model": imu_meta.get("model", ""), "serial": imu_meta.get("serial", "")},
        black_box_rad=black_box, problems=problems,
        notes=list(setup.notes) + ([renamed] if renamed else []) + list(est.notes),
        operator=str(run_meta.get("operator", "")))


__all__ = ["FORMAT", "VERSION", "TableCheckAnalysis", "analyse_log", "analyse_observations", "conversion_uncertainty",
           "table_check_observations"]
