"""Export formats of a compensation (`bench export`): JSON, CSV, a C header, kalibr-style YAML, TOML.

Every format holds the same numbers: per triad the compensation matrix `C` (SI input
units per counts/s), the bias `b` (counts/s), their 1-sigma uncertainties, the units, the
equation and who the calibration is for (IMU model and serial, run id, date, software
version). Numbers are written with `repr` (17 significant digits: they read back bit for
bit); an unknown uncertainty is JSON null, an empty CSV cell, C `NAN`, YAML `.nan` and
TOML `nan`. YAML and TOML are written by hand (no dependency); text from the result
(serial, model, run id) is quoted with JSON escapes, which YAML double-quoted strings
and TOML basic strings read alike, and never reaches C code outside a comment, where
`*/` and control characters are replaced.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from typing import Any, Callable

import numpy as np

from bench import __version__
from bench.calibration.compensation import EQUATIONS, RAW_UNIT, Compensation, TriadCompensation

COMPENSATION_FORMAT = "turntable-bench/compensation"
COMPENSATION_VERSION = 1

#: triad -> (what it measures, raw output name in the equation)
_MEASURES = {"gyro": ("body angular rate w_b", "F"), "acc": ("body specific force f_b", "J")}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _identity(c: Compensation) -> dict[str, str]:
    return {"imu_model": c.imu_model, "imu_serial": c.imu_serial, "run_id": c.run_id,
            "calibrated_utc": c.calibrated_utc, "calibration_software_version": c.software_version,
            "exported_by": f"turntable-bench {__version__}"}


def to_json(c: Compensation) -> str:
    """The versioned JSON document (format `turntable-bench/compensation`, version 1)."""
    def triad(t: TriadCompensation) -> dict[str, Any]:
        return {"measures": _MEASURES[t.sensor][0], "equation": EQUATIONS[t.sensor], "raw_unit": RAW_UNIT,
                "output_unit": t.input_unit,
                "matrix": t.matrix.tolist(), "matrix_unit": t.matrix_unit,
                "matrix_sigma": [[_num(x) for x in row] for row in t.matrix_sigma],
                "bias": t.bias_counts.tolist(), "bias_unit": RAW_UNIT,
                "bias_sigma": [_num(x) for x in t.bias_sigma]}

    doc = {"format": COMPENSATION_FORMAT, "version": COMPENSATION_VERSION, **_identity(c),
           "gyro": triad(c.gyro), "acc": triad(c.acc)}
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


CSV_COLUMNS = ("triad", "quantity", "row", "col", "value", "sigma", "unit")


def to_csv(c: Compensation) -> str:
    """One row per number: `triad,quantity,row,col,value,sigma,unit`; identity rows have triad `meta`."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    writer.writerow(["meta", "format", "", "", f"{COMPENSATION_FORMAT} {COMPENSATION_VERSION}", "", ""])
    for key, value in _identity(c).items():
        writer.writerow(["meta", key, "", "", value, "", ""])
    for t in c.triads():
        for i in range(3):
            for j in range(3):
                writer.writerow([t.sensor, "matrix", i, j, repr(float(t.matrix[i, j])),
                                 _csv_sigma(t.matrix_sigma[i, j]), t.matrix_unit])
        for i in range(3):
            writer.writerow([t.sensor, "bias", i, "", repr(float(t.bias_counts[i])), _csv_sigma(t.bias_sigma[i]),
                             RAW_UNIT])
    return out.getvalue()


def _csv_sigma(x: float) -> str:
    return repr(float(x)) if math.isfinite(x) else ""


# -- C header -------------------------------------------------------------------------------------

C_PREFIX = "TB_IMU"


def comment_text(text: str) -> str:
    """Text safe inside a C block comment: printable ASCII, no `*/`."""
    return re.sub(r"[^ -~]", "?", text).replace("*/", "*?")


def c_num(x: float) -> str:
    if not math.isfinite(x):
        return "NAN"
    text = repr(float(x))
    return text if any(ch in text for ch in ".e") else text + ".0"


def _c_array(name: str, values: np.ndarray, unit: str) -> str:
    if values.ndim == 1:
        body = "{" + ", ".join(map(c_num, values)) + "}"
        return f"static const double {name}[3] = {body};   /* {unit} */\n"
    rows = ",\n    ".join("{" + ", ".join(map(c_num, row)) + "}" for row in values)
    return f"static const double {name}[3][3] = {{\n    {rows}\n}};   /* {unit} */\n"


def to_c_header(c: Compensation) -> str:
    """A C header: `static const double` arrays and two inline functions applying them (C99)."""
    ident = _identity(c)
    lines = ["/* IMU compensation exported by turntable-bench (format "
             f"{COMPENSATION_FORMAT} {COMPENSATION_VERSION}).", " *"]
    lines += [f" * {key}: {comment_text(value) or '(not recorded)'}" for key, value in ident.items()]
    lines += [" *",
              " * gyro:          w_b[i] = sum_j TB_IMU_GYRO_MATRIX[i][j] * (F[j] - TB_IMU_GYRO_BIAS[j])",
              " * accelerometer: f_b[i] = sum_j TB_IMU_ACC_MATRIX[i][j] * (J[j] - TB_IMU_ACC_BIAS[j])",
              " * F, J: the raw outputs of sensors x, y, z in counts/s (increment per sample times the",
              " * sample rate); w_b in rad/s, f_b in m/s^2, along the body axes X, Y, Z.",
              " * *_SIGMA: 1-sigma uncertainties of the same elements (NAN: unknown).",
              " */",
              f"#ifndef {C_PREFIX}_COMPENSATION_H", f"#define {C_PREFIX}_COMPENSATION_H", "", "#include <math.h>", ""]
    text = "\n".join(lines) + "\n"
    for t in c.triads():
        name = f"{C_PREFIX}_{t.sensor.upper()}"
        text += _c_array(f"{name}_MATRIX", t.matrix, t.matrix_unit)
        text += _c_array(f"{name}_BIAS", t.bias_counts, RAW_UNIT)
        text += _c_array(f"{name}_MATRIX_SIGMA", t.matrix_sigma, t.matrix_unit)
        text += _c_array(f"{name}_BIAS_SIGMA", t.bias_sigma, RAW_UNIT)
        text += "\n"
    for t in c.triads():
        name, unit = f"{C_PREFIX}_{t.sensor.upper()}", t.input_unit
        text += (f"/* {_MEASURES[t.sensor][0]} ({unit}) from raw outputs (counts/s) */\n"
                 f"static inline void tb_imu_{t.sensor}_compensate(const double raw[3], double out[3])\n"
                 "{\n"
                 "    for (int i = 0; i < 3; ++i) {\n"
                 "        double sum = 0.0;\n"
                 f"        for (int j = 0; j < 3; ++j) sum += {name}_MATRIX[i][j] * (raw[j] - {name}_BIAS[j]);\n"
                 "        out[i] = sum;\n"
                 "    }\n"
                 "}\n\n")
    text += (f"/* the uncertainties, so that a file using only the functions above compiles without warnings */\n"
             f"static inline const double *tb_imu_sigmas(int which)\n"
             "{\n"
             f"    return which == 0 ? &{C_PREFIX}_GYRO_MATRIX_SIGMA[0][0] : which == 1 ? {C_PREFIX}_GYRO_BIAS_SIGMA\n"
             f"         : which == 2 ? &{C_PREFIX}_ACC_MATRIX_SIGMA[0][0] : {C_PREFIX}_ACC_BIAS_SIGMA;\n"
             "}\n\n"
             f"#endif /* {C_PREFIX}_COMPENSATION_H */\n")
    return text


# -- YAML (kalibr-style) ------------------------------------------------------------------------

def yaml_num(x: float) -> str:
    return repr(float(x)) if math.isfinite(x) else ".nan"


def _yaml_matrix(m: np.ndarray, indent: str) -> str:
    return "".join(f"{indent}- [{', '.join(map(yaml_num, row))}]\n" for row in m)


def _yaml_vector(v: np.ndarray) -> str:
    return "[" + ", ".join(map(yaml_num, v)) + "]"


def to_yaml(c: Compensation, rostopic: str = "/imu0", update_rate_hz: float | None = None) -> str:
    """The kalibr IMU-intrinsics layout (`imu0:` with `model: scale-misalignment`, `gyroscopes: {M, A,
    C_gyro_i}`, `accelerometers: {M}`), plus the biases and our compensation block.

    kalibr's `M` maps the true input to the measurement; here the measurement is the raw
    output in counts/s, so `M = diag(K) E` (counts/s per rad/s, per m/s^2) and `bias` is
    `b` in counts/s: `y = M u + bias`. `A` (g-sensitivity) is not part of this model (zeros),
    `C_gyro_i` is the identity (the gyro axes are in `M`). Noise densities are not written:
    this calibration does not measure them.
    """
    out = ["# IMU intrinsics from turntable-bench, kalibr-style layout (see bench.calibration.export)",
           "# measurement model: y = M u + bias (y raw counts/s; u rad/s or m/s^2)",
           "# compensation:      u = C (y - bias), C = M^-1"]
    out += ["imu0:", "  model: scale-misalignment", f"  rostopic: {json.dumps(rostopic)}", "  time_offset: 0.0"]
    if update_rate_hz is not None:
        out.append(f"  update_rate: {yaml_num(update_rate_hz)}")
    out += ["  T_i_b:"] + [f"    - [{', '.join('1.0' if i == j else '0.0' for j in range(4))}]" for i in range(4)]
    out += [f"  imu_model: {json.dumps(c.imu_model)}", f"  imu_serial: {json.dumps(c.imu_serial)}",
            f"  run_id: {json.dumps(c.run_id)}", f"  calibrated_utc: {json.dumps(c.calibrated_utc)}",
            f"  exported_by: {json.dumps(_identity(c)['exported_by'])}"]
    text = "\n".join(out) + "\n"
    for t, key in ((c.gyro, "gyroscopes"), (c.acc, "accelerometers")):
        forward = np.linalg.inv(t.matrix)
        text += f"  {key}:\n    M:   # {RAW_UNIT} per {t.input_unit}\n" + _yaml_matrix(forward, "      ")
        if t.sensor == "gyro":
            text += "    A:   # g-sensitivity, not in this model\n" + _yaml_matrix(np.zeros((3, 3)), "      ")
            text += "    C_gyro_i:\n" + _yaml_matrix(np.eye(3), "      ")
        text += f"    bias: {_yaml_vector(t.bias_counts)}   # {RAW_UNIT}\n"
        text += f"    bias_sigma: {_yaml_vector(t.bias_sigma)}\n"
        text += f"    compensation:   # {t.matrix_unit}\n" + _yaml_matrix(t.matrix, "      ")
        text += "    compensation_sigma:\n" + _yaml_matrix(t.matrix_sigma, "      ")
    return text


# -- TOML -----------------------------------------------------------------------------------------

def toml_num(x: float) -> str:
    return repr(float(x)) if math.isfinite(x) else "nan"


def _toml_matrix(m: np.ndarray) -> str:
    return "[\n" + "".join(f"  [{', '.join(map(toml_num, row))}],\n" for row in m) + "]"


def to_toml(c: Compensation) -> str:
    """The JSON document's content as TOML (tomllib reads it back)."""
    lines = [f"format = {json.dumps(COMPENSATION_FORMAT)}", f"version = {COMPENSATION_VERSION}"]
    lines += [f"{key} = {json.dumps(value)}" for key, value in _identity(c).items()]
    for t in c.triads():
        lines += ["", f"[{t.sensor}]", f"measures = {json.dumps(_MEASURES[t.sensor][0])}",
                  f"equation = {json.dumps(EQUATIONS[t.sensor])}", f"raw_unit = {json.dumps(RAW_UNIT)}",
                  f"output_unit = {json.dumps(t.input_unit)}", f"matrix_unit = {json.dumps(t.matrix_unit)}",
                  f"matrix = {_toml_matrix(t.matrix)}", f"matrix_sigma = {_toml_matrix(t.matrix_sigma)}",
                  f"bias_unit = {json.dumps(RAW_UNIT)}",
                  f"bias = [{', '.join(map(toml_num, t.bias_counts))}]",
                  f"bias_sigma = [{', '.join(map(toml_num, t.bias_sigma))}]"]
    return "\n".join(lines) + "\n"


#: format name -> writer; `bench export --format`
FORMATS: dict[str, Callable[[Compensation], str]] = {
    "json": to_json, "csv": to_csv, "c": to_c_header, "yaml": to_yaml, "toml": to_toml}


def export_text(c: Compensation, fmt: str) -> str:
    """The compensation in format `fmt` (one of `FORMATS`)."""
    return FORMATS[fmt](c)


__all__ = ["COMPENSATION_FORMAT", "COMPENSATION_VERSION", "CSV_COLUMNS", "FORMATS", "c_num", "comment_text",
           "export_text", "to_c_header", "to_csv", "to_json", "to_toml", "to_yaml", "toml_num", "yaml_num"]
