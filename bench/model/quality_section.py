"""The `quality` section of a calibration result: the solver's flags, each fit's chi-square, the residual outliers
and the uncertainty budget's summary (`bench.solve.calibrate.Calibration.quality` writes it).

Each part is a `bench.model.sections.Section`: read from a file it writes back what it read; an entry the file
lacks is None (an older file's). The budget's summary (`bench.solve.budget.Budget.summary_json`) stays the object
the file has: its readers (the reports) take it as it is.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bench.model.sections import Section, count, flag, list_of, number, obj, or_null, text


@dataclass
class FitQuality(Section):
    """One fit's figures (`quality.accelerometers`, `gyros`, `gyro_bias`): chi-square per degree of freedom per
    sensor axis (None: not finite), whether each axis' sigma was scaled up by the residual scatter, and for a
    least-squares fit its degrees of freedom and whether it was weighted (the gyro bias has neither)."""

    chi2_per_dof: list[float | None] | None = None
    dof: int | None = None
    weighted: bool | None = None
    sigma_scaled: list[bool] | None = None

    READERS = {"chi2_per_dof": list_of(or_null(number)), "dof": count, "weighted": flag,
               "sigma_scaled": list_of(flag)}


@dataclass
class Outlier(Section):
    """A residual beyond the outlier threshold: the step kind ("position" | "rotation"), its index in the residual
    table, the sensor axis (`acc_x` ... `gyro_z`) and the residual over its sigma."""

    step: str | None = None
    index: int | None = None
    sensor: str | None = None
    normalized: float | None = None

    READERS = {"step": text, "index": count, "sensor": text, "normalized": number}


@dataclass
class QualitySection(Section):
    """A result's `quality` section (None: an entry the solve did not write or the file lacks)."""

    flags: list[str] | None = None
    outlier_sigma: float | None = None          # the outlier threshold, residual / sigma
    accelerometers: FitQuality | None = None
    gyros: FitQuality | None = None
    gyro_bias: FitQuality | None = None
    outliers: list[Outlier] | None = None
    uncertainty: dict[str, Any] | None = None   # the budget's summary (`Budget.summary_json`)
    #: the extended model's significance table (`bench.solve.extended.ExtendedFit.significance_json`)
    significance: dict[str, Any] | None = None

    READERS = {"flags": list_of(text), "outlier_sigma": number, "accelerometers": FitQuality.from_dict,
               "gyros": FitQuality.from_dict, "gyro_bias": FitQuality.from_dict,
               "outliers": list_of(Outlier.from_dict), "uncertainty": obj, "significance": obj}

    def _dumped(self, name: str) -> Any:
        if name == "outliers":
            return None if self.outliers is None else [o.to_dict() for o in self.outliers]
        return super()._dumped(name)

    def fit(self, name: str) -> FitQuality | None:
        """The figures of the fit `name` (one of `FIT_NAMES`), None when the section has none."""
        if name not in FIT_NAMES:
            raise KeyError(name)
        fit: FitQuality | None = getattr(self, name)
        return fit


#: the fits a quality section can have, in the order the reports list them
FIT_NAMES = ("accelerometers", "gyros", "gyro_bias")

__all__ = ["FIT_NAMES", "FitQuality", "Outlier", "QualitySection"]
