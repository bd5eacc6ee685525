"""Versioned calibration result with a JSON round-trip (docs/explanation/model.md#result-file)."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from bench.files import InputFileError, parse_json, read_input_text, write_output_text
from bench.model.extended import EXTENDED_NAMES, EXTENDED_RESULT_UNITS
from bench.model.families import RESULT_UNITS, canonical_names, family_of
from bench.model.imu import ImuCoefficients
from bench.model.quality_section import QualitySection
from bench.model.run_section import RunInfo
from bench.model.sections import ResultFormatError
from bench.model.verdict_section import VerdictSection

RESULT_FORMAT = "turntable-bench/result"
RESULT_VERSION = 2
#: versions this software reads: 1 had no uncertainty budget (its sigma covered sample noise only)
READABLE_VERSIONS = (1, 2)


@dataclass(frozen=True)
class Coefficient:
    """One solved coefficient in display units with its 1-sigma uncertainty.

    From version 2, `sigma` is the combined standard uncertainty of `budget` (component
    -> standard uncertainty, display units) and `expanded` is k times it.
    """

    value: float
    sigma: float
    unit: str
    budget: dict[str, float] | None = None
    k: float | None = None

    @property
    def expanded(self) -> float:
        return self.k * self.sigma if self.k is not None else math.nan

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"value": self.value, "sigma": _json_float(self.sigma), "unit": self.unit}
        if self.k is not None:
            out["expanded"] = _json_float(self.expanded)
            out["k"] = self.k
        if self.budget is not None:
            out["budget"] = {name: _json_float(v) for name, v in self.budget.items()}
        return out


def _json_float(x: float) -> float | None:
    # JSON has no NaN: an unknown uncertainty is written as null.
    return None if x is None or not math.isfinite(x) else float(x)


def coefficient_table(values: dict[str, float], sigmas: dict[str, float] | None = None,
                      budgets: dict[str, dict[str, float]] | None = None,
                      k: float | None = None) -> dict[str, Coefficient]:
    """Canonical-ordered coefficient table from display-unit values (and sigmas, budgets, k); the extended
    model's coefficients (`bench.model.extended`) follow the 30."""
    sigmas = sigmas or {}
    return {name: Coefficient(float(values[name]), float(sigmas.get(name, math.nan)),
                              _UNITS[family_of(name)][0],
                              None if budgets is None else dict(budgets.get(name, {})), k)
            for name in _KNOWN if name in values}


#: every coefficient a result may hold, in order: the 30, then the extended model's; prefix -> unit
_KNOWN = (*canonical_names(), *EXTENDED_NAMES)
_UNITS = {**RESULT_UNITS, **EXTENDED_RESULT_UNITS}


@dataclass
class CalibrationResult:
    """What a calibration produced: coefficients, residuals, quality, run metadata.

    `coefficients` may hold a subset of the 30 canonical names (e.g. a positions-only
    solve has no gyro scale factors). `sim_truth`, for simulated runs, holds the true
    coefficients in the same shape. The `quality`, `run` and `verdict` sections are typed
    (`bench.model.sections`): read from a file, each writes back what it read.
    """

    coefficients: dict[str, Coefficient]
    residuals: dict[str, Any] = field(default_factory=dict)
    quality: QualitySection = field(default_factory=QualitySection)
    run: RunInfo = field(default_factory=RunInfo.empty)
    sim_truth: dict[str, Coefficient] | None = None
    #: the acceptance verdict (`bench.acceptance.verdict.Verdict.to_section`), when judged
    verdict: VerdictSection | None = None
    #: the IMU's temperature over the run (`mean_c`, `min_c`, `max_c`, degC; `source`), when known:
    #: what a thermal model (`bench.thermal`) places the result at
    temperature: dict[str, Any] | None = None

    def __post_init__(self) -> None:
        # A section given as its entries (a script's `CalibrationResult(..., run={"run_id": ...})`) is read as
        # a file's would be: typed, malformed entries refused by name.
        if isinstance(self.run, Mapping):
            self.run = RunInfo.from_dict(self.run, "run", complete=False)
        if isinstance(self.quality, Mapping):
            self.quality = QualitySection.from_dict(self.quality, "quality")
        if isinstance(self.verdict, Mapping):
            self.verdict = VerdictSection.from_dict(self.verdict, "verdict")

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": RESULT_FORMAT,
            "version": RESULT_VERSION,
        }
        if self.verdict is not None:        # first: what a reader wants to know first
            out["verdict"] = self.verdict.to_dict()
        out |= {
            "coefficients": {k: c.to_json() for k, c in self.coefficients.items()},
            "residuals": self.residuals,
            "quality": self.quality.to_dict(),
            "run": self.run.to_dict(),
        }
        if self.temperature is not None:
            out["temperature"] = self.temperature
        if self.sim_truth is not None:
            out["sim_truth"] = {"coefficients": {k: c.to_json() for k, c in self.sim_truth.items()}}
        return out

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2, allow_nan=False)

    def save(self, path: str | Path) -> None:
        """Write the result (never over a run log; renamed into place once written)."""
        write_output_text(path, self.dumps() + "\n")

    @classmethod
    def from_json(cls, data: dict[str, Any], origin: str = "<result>") -> "CalibrationResult":
        if not isinstance(data, dict) or data.get("format") != RESULT_FORMAT:
            raise ResultFormatError(f"{origin}: not a {RESULT_FORMAT} file")
        version = data.get("version")
        if isinstance(version, bool) or version not in READABLE_VERSIONS:
            raise ResultFormatError(f"{origin}: result version {version!r} is not supported "
                                    f"(this software reads versions {', '.join(map(str, READABLE_VERSIONS))})")
        truth = data.get("sim_truth")
        verdict = data.get("verdict")
        try:        # a section of an older file may lack entries (None); a malformed one is refused, named
            quality = QualitySection.from_dict(data.get("quality", {}), "quality")
            run = RunInfo.from_dict(data.get("run", {}), "run", complete=False)
            judged = None if verdict is None else VerdictSection.from_dict(verdict, "verdict")
        except ResultFormatError as exc:
            raise ResultFormatError(f"{origin}: {exc}") from exc
        return cls(
            coefficients=_read_table(data.get("coefficients"), origin, "coefficients"),
            residuals=data.get("residuals", {}),
            quality=quality,
            run=run,
            sim_truth=None if truth is None else _read_table(truth.get("coefficients"), origin,
                                                             "sim_truth.coefficients"),
            verdict=judged,
            temperature=_read_temperature(data.get("temperature"), origin),
        )

    @classmethod
    def loads(cls, text: str, origin: str = "<result>") -> "CalibrationResult":
        try:
            data = parse_json(text, origin)
        except InputFileError as exc:
            raise ResultFormatError(str(exc)) from None
        return cls.from_json(data, origin)

    @classmethod
    def load(cls, path: str | Path) -> "CalibrationResult":
        """A result file from outside: a regular file of at most `MAX_INPUT_FILE_BYTES` (`InputError` in one line;
        OSError when it cannot be opened)."""
        return cls.loads(read_input_text(path, what="result file"), str(path))

    def values(self) -> dict[str, float]:
        return {k: c.value for k, c in self.coefficients.items()}

    def imu_coefficients(self) -> ImuCoefficients:
        """All 30 coefficients as an `ImuCoefficients` (KeyError if the result lacks some)."""
        return ImuCoefficients.from_canonical(self.values())


def _read_temperature(section: Any, origin: str) -> dict[str, Any] | None:
    if section is None:
        return None
    mean = section.get("mean_c") if isinstance(section, dict) else None
    if isinstance(mean, bool) or not isinstance(mean, (int, float)) or not math.isfinite(mean):
        raise ResultFormatError(f"{origin}: temperature.mean_c must be a finite number of degC")
    return section


def _read_table(table: Any, origin: str, where: str) -> dict[str, Coefficient]:
    if not isinstance(table, dict):
        raise ResultFormatError(f"{origin}: {where} must be an object")
    known = set(_KNOWN)
    out = {}
    for name, entry in table.items():
        if name not in known:
            raise ResultFormatError(f"{origin}: {where}.{name}: unknown coefficient name")
        try:
            sigma = entry.get("sigma")
            budget, k = entry.get("budget"), entry.get("k")
            if budget is not None:
                budget = {str(c): math.nan if v is None else float(v) for c, v in budget.items()}
            out[name] = Coefficient(float(entry["value"]), math.nan if sigma is None else float(sigma),
                                    str(entry["unit"]), budget, None if k is None else float(k))
        except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
            raise ResultFormatError(f"{origin}: {where}.{name}: needs value, sigma and unit (and a budget of "
                                    "numbers, when given)") from exc
        expected = _UNITS[family_of(name)][0]
        if out[name].unit != expected:
            raise ResultFormatError(f"{origin}: {where}.{name}: unit {out[name].unit!r}, expected {expected!r}")
    return out
