"""The thermal model of an IMU: every coefficient's polynomial in temperature, from calibrations at
several temperatures, and its versioned result file (`*.thermal.json`).

The inputs are calibration results from any source (an in-memory simulated run, result
files on disk, later the chamber-driven plan); each needs the IMU's mean temperature
over its run (the result's `temperature` section, or one given with it).

File (format `turntable-bench/thermal`, version 1):
    {"format", "version",
     "thermal_model": {"format": "turntable-bench/thermal-model", "version": 1, "reference_c",
                       "degree_rule", "uncertainty_rule", "alpha", "temperature_range_c",
                       "coefficients": {name: CoefficientFit.to_json()}},
     "points": [{"label", "temperature": {...}, "coefficients": {name: {value, sigma, unit}}}],
     "notes": [...], "run": {...}, "sim_truth": {...} (simulated runs)}
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from bench.errors import InputError
from bench.files import InputFileError, parse_json, read_input_text, write_output_text
from bench.model.families import RESULT_UNITS, canonical_names, family_of
from bench.model.result import CalibrationResult
from bench.model.thermal import DIAGONAL_NAMES
from bench.solve.budget import common_sigma
from bench.thermal.fit import ALPHA, DEGREE_RULE, UNCERTAINTY_RULE, CoefficientFit, ThermalFitError, fit_coefficient

THERMAL_FORMAT = "turntable-bench/thermal"
THERMAL_VERSION = 1
MODEL_FORMAT = "turntable-bench/thermal-model"
MODEL_VERSION = 1
#: temperatures closer than this are one temperature (a repeated calibration), degC
SAME_TEMPERATURE_C = 1e-6


class ThermalFormatError(InputError):
    """A file that is not a thermal result of a version we read."""


@dataclass(frozen=True)
class ThermalPoint:
    """One calibration at one temperature."""

    label: str                      # where it came from (a file name, "sim -20 degC")
    temperature: dict[str, Any]     # mean_c (used), min_c, max_c, source ...
    result: CalibrationResult

    @property
    def temperature_c(self) -> float:
        return float(self.temperature["mean_c"])


def point_from_result(result: CalibrationResult, label: str, temperature_c: float | None = None) -> ThermalPoint:
    """A point from a result: its `temperature` section, or `temperature_c` given for it (which wins)."""
    if temperature_c is not None:
        if not math.isfinite(temperature_c):
            raise InputError(f"{label}: the temperature must be a finite number")
        temperature = {"mean_c": float(temperature_c), "source": "given"}
    elif result.temperature is not None:
        temperature = dict(result.temperature)
    else:
        raise InputError(f"{label}: the result records no IMU temperature (no 'temperature' section); "
                         "give it as FILE@DEGC")
    return ThermalPoint(label, temperature, result)


def _identity_entry(point: ThermalPoint) -> dict[str, Any]:
    """A point's `imu` entry (the IMU its calibration names; nothing when it names none): the export's header
    says which IMU the model is of, after the model is read back from its file."""
    imu = point.result.run.imu
    return {} if imu is None or not (imu.model or imu.serial) else {"imu": imu.to_dict()}


@dataclass
class ThermalModel:
    """Per-coefficient thermal polynomials and what they were fitted to."""

    reference_c: float
    fits: dict[str, CoefficientFit]
    points: list[ThermalPoint]
    notes: list[str] = field(default_factory=list)
    run: dict[str, Any] = field(default_factory=dict)
    #: simulated runs: name -> [value at reference, c1, c2, c3] of the truth, display units
    sim_truth: dict[str, list[float]] | None = None
    sim_truth_reference_c: float | None = None

    @property
    def range_c(self) -> tuple[float, float]:
        temps = [p.temperature_c for p in self.points]
        return min(temps), max(temps)

    def evaluate(self, temperature_c: float) -> dict[str, tuple[float, float]]:
        """Every modelled coefficient at `temperature_c`: name -> (value, 1-sigma of the fit)."""
        return {name: (float(f.value(temperature_c)), float(f.sigma_at(temperature_c)))
                for name, f in self.fits.items()}

    def truth_at(self, name: str, temperature_c: float) -> float | None:
        """The simulated truth of `name` at `temperature_c` (None without a truth)."""
        if self.sim_truth is None or name not in self.sim_truth or self.sim_truth_reference_c is None:
            return None
        dt = temperature_c - self.sim_truth_reference_c
        return float(sum(c * dt ** k for k, c in enumerate(self.sim_truth[name])))

    # -- file --------------------------------------------------------------------------
    def model_json(self) -> dict[str, Any]:
        """The versioned `thermal_model` section."""
        low, high = self.range_c
        return {"format": MODEL_FORMAT, "version": MODEL_VERSION, "reference_c": self.reference_c,
                "degree_rule": DEGREE_RULE, "uncertainty_rule": UNCERTAINTY_RULE, "alpha": ALPHA,
                "temperature_range_c": [low, high],
                "coefficients": {name: f.to_json() for name, f in self.fits.items()}}

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": THERMAL_FORMAT, "version": THERMAL_VERSION,
                               "thermal_model": self.model_json(),
                               "points": [{"label": p.label, "temperature": p.temperature,
                                           "coefficients": {k: c.to_json() for k, c in p.result.coefficients.items()},
                                           **_identity_entry(p)}
                                          for p in self.points],
                               "notes": list(self.notes), "run": self.run}
        if self.sim_truth is not None:
            out["sim_truth"] = {"reference_c": self.sim_truth_reference_c, "polynomials": self.sim_truth}
        return out

    def dumps(self) -> str:
        return json.dumps(self.to_json(), indent=2, allow_nan=False)

    def save(self, path: str | Path) -> None:
        write_output_text(path, self.dumps() + "\n")

    @classmethod
    def from_json(cls, data: Any, origin: str = "<thermal>") -> "ThermalModel":
        if not isinstance(data, dict) or data.get("format") != THERMAL_FORMAT:
            raise ThermalFormatError(f"{origin}: not a {THERMAL_FORMAT} file")
        if data.get("version") != THERMAL_VERSION:
            raise ThermalFormatError(f"{origin}: thermal version {data.get('version')!r} is not supported "
                                     f"(this software reads version {THERMAL_VERSION})")
        section = data.get("thermal_model")
        if not isinstance(section, dict) or section.get("format") != MODEL_FORMAT \
                or section.get("version") != MODEL_VERSION:
            raise ThermalFormatError(f"{origin}: thermal_model: not a {MODEL_FORMAT} version {MODEL_VERSION} section")
        reference = section.get("reference_c")
        if isinstance(reference, bool) or not isinstance(reference, (int, float)) or not math.isfinite(reference):
            raise ThermalFormatError(f"{origin}: thermal_model.reference_c must be a finite number")
        fits = {}
        known = set(canonical_names())
        table = section.get("coefficients")
        if not isinstance(table, dict):
            raise ThermalFormatError(f"{origin}: thermal_model.coefficients must be an object")
        for name, entry in table.items():
            if name not in known:
                raise ThermalFormatError(f"{origin}: thermal_model.coefficients.{name}: unknown coefficient name")
            try:
                fits[name] = CoefficientFit.from_json(name, float(reference), entry)
            except (KeyError, TypeError, ValueError, AttributeError) as exc:
                raise ThermalFormatError(f"{origin}: thermal_model.coefficients.{name}: malformed ({exc})") from exc
        points = []
        for k, p in enumerate(data.get("points") or []):
            try:
                result = CalibrationResult.from_json({"format": "turntable-bench/result", "version": 1,
                                                      "coefficients": p["coefficients"],
                                                      "temperature": p["temperature"],
                                                      **({"run": {"imu": p["imu"]}} if "imu" in p else {})},
                                                     f"{origin}: points[{k}]")
                points.append(ThermalPoint(str(p["label"]), dict(p["temperature"]), result))
            except (KeyError, TypeError, AttributeError) as exc:
                raise ThermalFormatError(f"{origin}: points[{k}]: malformed ({exc})") from exc
        if not points:
            raise ThermalFormatError(f"{origin}: no points")
        truth = data.get("sim_truth")
        return cls(float(reference), fits, points, [str(n) for n in data.get("notes") or []],
                   run if isinstance(run := data.get("run"), dict) else {},
                   None if not isinstance(truth, dict) else {k: [float(c) for c in v]
                                                             for k, v in truth.get("polynomials", {}).items()},
                   None if not isinstance(truth, dict) else float(truth["reference_c"]))

    @classmethod
    def loads(cls, text: str, origin: str = "<thermal>") -> "ThermalModel":
        try:
            data = parse_json(text, origin)
        except InputFileError as exc:
            raise ThermalFormatError(str(exc)) from None
        return cls.from_json(data, origin)

    @classmethod
    def load(cls, path: str | Path) -> "ThermalModel":
        """A thermal file from outside, bounded as a result file is (`ThermalFormatError` in one line; OSError
        when it cannot be read)."""
        return cls.loads(read_bounded_text(str(path)), str(path))


def read_bounded_text(path: str) -> str:
    """The UTF-8 text of a regular file of at most `MAX_INPUT_FILE_BYTES` (`InputError` otherwise)."""
    return read_input_text(path, what="result or thermal file")


def is_thermal_text(text: str) -> bool:
    """Whether `text` is JSON of a thermal file (any version), to tell it from a calibration result."""
    try:
        data = parse_json(text, "<thermal>")
    except InputError:
        return False
    return isinstance(data, dict) and data.get("format") == THERMAL_FORMAT


def _serial(point: ThermalPoint) -> str:
    imu = point.result.run.imu
    return str(imu.serial or "") if imu is not None else ""


def _common_parts(name: str, entries: list, sigmas: np.ndarray) -> np.ndarray | None:
    """Each point's common part of its sigma (`bench.solve.budget.common_sigma`: the table's, the site's), from
    the points' budgets; None when a point has no budget (the fit then bounds the common part itself), and for
    a direction-cosine diagonal: it is second order in its row's off-diagonals, so the table's error in it
    changes with their temperature terms (not common: split, its terms came out 20 sigma off)."""
    if name in DIAGONAL_NAMES or any(e.budget is None for e in entries):
        return None
    return np.minimum([common_sigma(e.budget) for e in entries], sigmas)


def fit_thermal_model(points: list[ThermalPoint], reference_c: float = 25.0) -> ThermalModel:
    """Fit every coefficient the points share (module `bench.thermal.fit`: degree rule, uncertainty).

    A coefficient missing from a point, or without a sigma there, is left out with a note; calibrations
    of IMUs with different serial numbers are refused.
    """
    if len(points) < 2:
        raise ThermalFitError(f"a thermal model needs calibrations at two temperatures at least, got {len(points)}")
    points = sorted(points, key=lambda p: p.temperature_c)
    serials = {p.label: _serial(p) for p in points if _serial(p)}
    if len(set(serials.values())) > 1:
        raise ThermalFitError("the calibrations are of different IMUs: "
                              + ", ".join(f"{label}: serial {serial!r}" for label, serial in serials.items()))
    temps = np.array([p.temperature_c for p in points])
    if len(np.unique(np.round(temps / SAME_TEMPERATURE_C))) < 2:
        raise ThermalFitError("the calibrations are all at one temperature: nothing to fit in temperature")
    notes: list[str] = []
    fits: dict[str, CoefficientFit] = {}
    for name in canonical_names():
        entries = [p.result.coefficients.get(name) for p in points]
        present = [e for e in entries if e is not None]
        if not present:
            continue
        if len(present) < len(entries):
            missing = [p.label for p, e in zip(points, entries) if e is None]
            notes.append(f"{name}: not modelled, missing from {', '.join(missing)}")
            continue
        sigmas = np.array([e.sigma for e in present])
        if not (np.all(np.isfinite(sigmas)) and np.all(sigmas > 0)):
            bad = [p.label for p, s in zip(points, sigmas) if not (math.isfinite(s) and s > 0)]
            notes.append(f"{name}: not modelled, no uncertainty in {', '.join(bad)}")
            continue
        fits[name] = fit_coefficient(name, RESULT_UNITS[family_of(name)][0], temps,
                                     [e.value for e in present], sigmas, reference_c,
                                     common_sigmas=_common_parts(name, present, sigmas))
    if not fits:
        raise ThermalFitError("no coefficient is present with an uncertainty in every calibration")
    return ThermalModel(float(reference_c), fits, points, notes)


__all__ = ["MODEL_FORMAT", "MODEL_VERSION", "THERMAL_FORMAT", "THERMAL_VERSION", "ThermalFormatError",
           "ThermalModel", "ThermalPoint", "fit_thermal_model", "is_thermal_text", "point_from_result",
           "read_bounded_text"]
