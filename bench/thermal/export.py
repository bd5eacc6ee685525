"""Export formats of a thermal model (`bench export THERMAL.json`): JSON, CSV, a C header, YAML, TOML.

Every format holds the same numbers: per coefficient its unit, the degree, the
polynomial c0..c3 in (T - reference_c) (unit per degC^k; zeros beyond the degree), the
coefficients' 1-sigma and covariance, and the calibrated temperature range; plus who
it is for. Numbers are written with `repr` (they read back bit for bit), as
`bench.calibration.export` writes a compensation; coefficient names are canonical
identifiers (`Kg_x`), units and identity text are quoted with JSON escapes (YAML and
TOML read them alike) and reach C only inside comments, made safe there.
"""

from __future__ import annotations

import csv
import io
import json
from typing import Any, Callable

import numpy as np

from bench import __version__
from bench.calibration.export import c_num, comment_text, toml_num, yaml_num
from bench.thermal.fit import MAX_DEGREE
from bench.thermal.model import MODEL_FORMAT, MODEL_VERSION, ThermalModel

TERMS = MAX_DEGREE + 1
EQUATION = "value(T) = sum_k polynomial[k] * (T - reference_c)^k, T the IMU temperature in degC"


def _padded(model: ThermalModel, name: str) -> tuple[np.ndarray, np.ndarray]:
    """(polynomial (4,), covariance (4, 4)) of `name`, zeros beyond its degree."""
    fit = model.fits[name]
    poly, cov = np.zeros(TERMS), np.zeros((TERMS, TERMS))
    poly[:fit.degree + 1] = fit.polynomial
    cov[:fit.degree + 1, :fit.degree + 1] = fit.covariance
    return poly, cov


def _identity(model: ThermalModel) -> dict[str, str]:
    imu = model.points[0].result.run.imu if model.points else None
    model_name, serial = (imu.model, imu.serial) if imu is not None else (None, None)
    return {"imu_model": str(model_name or ""), "imu_serial": str(serial or ""),
            "exported_by": f"turntable-bench {__version__}"}


def to_json(model: ThermalModel) -> str:
    low, high = model.range_c
    coefficients: dict[str, Any] = {}
    for name, fit in model.fits.items():
        poly, cov = _padded(model, name)
        coefficients[name] = {"unit": fit.unit, "degree": fit.degree, "polynomial": poly.tolist(),
                              "polynomial_sigma": np.sqrt(np.diag(cov)).tolist(), "covariance": cov.tolist()}
    doc = {"format": MODEL_FORMAT, "version": MODEL_VERSION, **_identity(model), "equation": EQUATION,
           "reference_c": model.reference_c, "temperature_range_c": [low, high], "coefficients": coefficients}
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


CSV_COLUMNS = (("name", "unit", "degree", "reference_c", "min_c", "max_c")
               + tuple(f"c{k}" for k in range(TERMS)) + tuple(f"sigma_c{k}" for k in range(TERMS))
               + tuple(f"cov_{i}{j}" for i in range(TERMS) for j in range(i, TERMS)))


def to_csv(model: ThermalModel) -> str:
    """One row per coefficient (columns `CSV_COLUMNS`); the identity in rows named `#meta`."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    blanks = [""] * (len(CSV_COLUMNS) - 2)
    writer.writerow(["#meta", "format", f"{MODEL_FORMAT} {MODEL_VERSION}"] + blanks[1:])
    for key, value in _identity(model).items():
        writer.writerow(["#meta", key, value] + blanks[1:])
    low, high = model.range_c
    for name, fit in model.fits.items():
        poly, cov = _padded(model, name)
        writer.writerow([name, fit.unit, fit.degree, repr(model.reference_c), repr(low), repr(high)]
                        + [repr(float(c)) for c in poly] + [repr(float(s)) for s in np.sqrt(np.diag(cov))]
                        + [repr(float(cov[i, j])) for i in range(TERMS) for j in range(i, TERMS)])
    return out.getvalue()


C_PREFIX = "TB_IMU_THERMAL"


def to_c_header(model: ThermalModel) -> str:
    """`static const double` tables indexed by an enum of the coefficient names, and inline
    functions for a coefficient's value and 1-sigma at a temperature (C99)."""
    names = list(model.fits)
    low, high = model.range_c
    lines = [f"/* IMU thermal model exported by turntable-bench (format {MODEL_FORMAT} {MODEL_VERSION}).", " *"]
    lines += [f" * {key}: {comment_text(value) or '(not recorded)'}" for key, value in _identity(model).items()]
    lines += [" *", f" * {EQUATION}.",
              f" * Calibrated from {low:g} to {high:g} degC; units per coefficient below (display units).",
              " */", f"#ifndef {C_PREFIX}_H", f"#define {C_PREFIX}_H", "", "#include <math.h>", "",
              f"#define {C_PREFIX}_COUNT {len(names)}", f"#define {C_PREFIX}_TERMS {TERMS}",
              f"#define {C_PREFIX}_REFERENCE_C {c_num(model.reference_c)}",
              f"#define {C_PREFIX}_MIN_C {c_num(low)}", f"#define {C_PREFIX}_MAX_C {c_num(high)}", "",
              "enum tb_imu_thermal_coefficient {"]
    lines += [f"    {C_PREFIX}_{name} = {k}," for k, name in enumerate(names)]
    lines += ["};", "", f"static const char *const {C_PREFIX}_NAMES[{C_PREFIX}_COUNT] = {{"]
    lines += [f"    \"{name}\",   /* {comment_text(model.fits[name].unit)} */" for name in names]
    lines += ["};", "", f"static const double {C_PREFIX}_POLY[{C_PREFIX}_COUNT][{C_PREFIX}_TERMS] = {{"]
    for name in names:
        poly, _ = _padded(model, name)
        lines.append("    {" + ", ".join(map(c_num, poly)) + f"}},   /* {name} */")
    lines += ["};", "",
              f"static const double {C_PREFIX}_COV[{C_PREFIX}_COUNT][{C_PREFIX}_TERMS][{C_PREFIX}_TERMS] = {{"]
    for name in names:
        _, cov = _padded(model, name)
        rows = ", ".join("{" + ", ".join(map(c_num, row)) + "}" for row in cov)
        lines.append(f"    {{{rows}}},   /* {name} */")
    lines += ["};", "",
              "/* coefficient k at IMU temperature t_c (degC) */",
              "static inline double tb_imu_thermal_value(int k, double t_c)",
              "{",
              f"    const double x = t_c - {C_PREFIX}_REFERENCE_C;",
              "    double sum = 0.0;",
              f"    for (int i = {C_PREFIX}_TERMS - 1; i >= 0; --i) sum = sum * x + {C_PREFIX}_POLY[k][i];",
              "    return sum;",
              "}", "",
              "/* 1-sigma of the model's value of coefficient k at t_c */",
              "static inline double tb_imu_thermal_sigma(int k, double t_c)",
              "{",
              f"    const double x = t_c - {C_PREFIX}_REFERENCE_C;",
              f"    double p[{C_PREFIX}_TERMS], var = 0.0;",
              "    p[0] = 1.0;",
              f"    for (int i = 1; i < {C_PREFIX}_TERMS; ++i) p[i] = p[i - 1] * x;",
              f"    for (int i = 0; i < {C_PREFIX}_TERMS; ++i)",
              f"        for (int j = 0; j < {C_PREFIX}_TERMS; ++j) var += p[i] * {C_PREFIX}_COV[k][i][j] * p[j];",
              "    return sqrt(var);",
              "}", "",
              f"#endif /* {C_PREFIX}_H */", ""]
    return "\n".join(lines)


def to_yaml(model: ThermalModel) -> str:
    low, high = model.range_c
    ident = _identity(model)
    out = ["# IMU thermal model from turntable-bench (see bench.thermal.export)", f"# {EQUATION}",
           f"format: {json.dumps(MODEL_FORMAT)}", f"version: {MODEL_VERSION}"]
    out += [f"{key}: {json.dumps(value)}" for key, value in ident.items()]
    out += [f"reference_c: {yaml_num(model.reference_c)}",
            f"temperature_range_c: [{yaml_num(low)}, {yaml_num(high)}]", "coefficients:"]
    for name, fit in model.fits.items():
        poly, cov = _padded(model, name)
        out += [f"  {name}:", f"    unit: {json.dumps(fit.unit)}", f"    degree: {fit.degree}",
                f"    polynomial: [{', '.join(map(yaml_num, poly))}]",
                f"    polynomial_sigma: [{', '.join(map(yaml_num, np.sqrt(np.diag(cov))))}]", "    covariance:"]
        out += [f"      - [{', '.join(map(yaml_num, row))}]" for row in cov]
    return "\n".join(out) + "\n"


def to_toml(model: ThermalModel) -> str:
    low, high = model.range_c
    lines = [f"format = {json.dumps(MODEL_FORMAT)}", f"version = {MODEL_VERSION}"]
    lines += [f"{key} = {json.dumps(value)}" for key, value in _identity(model).items()]
    lines += [f"equation = {json.dumps(EQUATION)}", f"reference_c = {toml_num(model.reference_c)}",
              f"temperature_range_c = [{toml_num(low)}, {toml_num(high)}]"]
    for name, fit in model.fits.items():
        poly, cov = _padded(model, name)
        lines += ["", f"[coefficients.{name}]", f"unit = {json.dumps(fit.unit)}", f"degree = {fit.degree}",
                  f"polynomial = [{', '.join(map(toml_num, poly))}]",
                  f"polynomial_sigma = [{', '.join(map(toml_num, np.sqrt(np.diag(cov))))}]",
                  "covariance = [" + ", ".join("[" + ", ".join(map(toml_num, row)) + "]" for row in cov) + "]"]
    return "\n".join(lines) + "\n"


#: format name -> writer (the same names as `bench.calibration.export.FORMATS`)
FORMATS: dict[str, Callable[[ThermalModel], str]] = {
    "json": to_json, "csv": to_csv, "c": to_c_header, "yaml": to_yaml, "toml": to_toml}


def export_thermal(model: ThermalModel, fmt: str) -> str:
    return FORMATS[fmt](model)


__all__ = ["CSV_COLUMNS", "EQUATION", "FORMATS", "export_thermal", "to_c_header", "to_csv", "to_json", "to_toml",
           "to_yaml"]
