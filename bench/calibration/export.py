"""Export formats of a compensation (`bench export`): JSON, CSV, a C header, an IMU file for kalibr (YAML), TOML.

Every format holds the same numbers: per triad the compensation matrix `C` (SI input
units per counts/s), the bias `b` (counts/s), their 1-sigma uncertainties, the units, the
equation and who the calibration is for (IMU model and serial, run id, date, software
version). Numbers are written with `repr` (17 significant digits: they read back bit for
bit); an unknown uncertainty is JSON null, an empty CSV cell, C `NAN`, YAML `.nan` and
TOML `nan`. YAML and TOML are written by hand (no dependency); text from the result
(serial, model, run id) is quoted with JSON escapes, which YAML double-quoted strings
and TOML basic strings read alike, and never reaches C code outside a comment, where
`*/` and control characters are replaced.

A result of the extended model adds its families to every format (`bench.calibration.export_higher_order`); a
result of the 30 coefficients exports exactly as it did before them.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from bench import __version__
from bench.calibration import export_higher_order as higher
from bench.calibration.compensation import EQUATIONS, RAW_UNIT, Compensation, TriadCompensation
from bench.errors import InputError
from bench.model.noise_result import NoiseResult
from bench.model.units import DEG, MICRO_G

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
    if c.higher_order is not None:
        doc["version"] = higher.HIGHER_ORDER_VERSION
        doc["higher_order"] = higher.higher_order_doc(c)
    if c.time_offset is not None:
        doc["time_offset"] = higher.time_offset_doc(c)
    return json.dumps(doc, indent=2, allow_nan=False) + "\n"


CSV_COLUMNS = ("triad", "quantity", "row", "col", "value", "sigma", "unit")


def to_csv(c: Compensation) -> str:
    """One row per number: `triad,quantity,row,col,value,sigma,unit`; identity rows have triad `meta`."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(CSV_COLUMNS)
    version = COMPENSATION_VERSION if c.higher_order is None else higher.HIGHER_ORDER_VERSION
    writer.writerow(["meta", "format", "", "", f"{COMPENSATION_FORMAT} {version}", "", ""])
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
    if c.higher_order is not None:
        writer.writerows(higher.csv_rows(c))
    if c.time_offset is not None:
        writer.writerow(higher.time_offset_csv_row(c))
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
    version = COMPENSATION_VERSION if c.higher_order is None else higher.HIGHER_ORDER_VERSION
    lines = ["/* IMU compensation exported by turntable-bench (format "
             f"{COMPENSATION_FORMAT} {version}).", " *"]
    lines += [f" * {key}: {comment_text(value) or '(not recorded)'}" for key, value in ident.items()]
    lines += [" *",
              " * gyro:          w_b[i] = sum_j TB_IMU_GYRO_MATRIX[i][j] * (F[j] - TB_IMU_GYRO_BIAS[j])",
              " * accelerometer: f_b[i] = sum_j TB_IMU_ACC_MATRIX[i][j] * (J[j] - TB_IMU_ACC_BIAS[j])",
              " * F, J: the raw outputs of sensors x, y, z in counts/s (increment per sample times the",
              " * sample rate); w_b in rad/s, f_b in m/s^2, along the body axes X, Y, Z.",
              " * *_SIGMA: 1-sigma uncertainties of the same elements (NAN: unknown).",
              *(higher.c_comment_lines() if c.higher_order is not None else []),
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
    if c.higher_order is not None:
        text += higher.c_arrays(c, C_PREFIX, _c_array)
    if c.time_offset is not None:
        text += higher.time_offset_c_lines(c, C_PREFIX, c_num)
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
    if c.higher_order is not None:
        text += higher.c_function(c, C_PREFIX)
    text += (f"/* the uncertainties, so that a file using only the functions above compiles without warnings */\n"
             f"static inline const double *tb_imu_sigmas(int which)\n"
             "{\n"
             f"    return which == 0 ? &{C_PREFIX}_GYRO_MATRIX_SIGMA[0][0] : which == 1 ? {C_PREFIX}_GYRO_BIAS_SIGMA\n"
             f"         : which == 2 ? &{C_PREFIX}_ACC_MATRIX_SIGMA[0][0] : {C_PREFIX}_ACC_BIAS_SIGMA;\n"
             "}\n\n"
             f"#endif /* {C_PREFIX}_COMPENSATION_H */\n")
    return text


# -- YAML for kalibr -------------------------------------------------------------------------------

def yaml_num(x: float) -> str:
    return repr(float(x)) if math.isfinite(x) else ".nan"


def _yaml_matrix(m: np.ndarray, indent: str) -> str:
    return "".join(f"{indent}- [{', '.join(map(yaml_num, row))}]\n" for row in m)


def _yaml_vector(v: np.ndarray) -> str:
    return "[" + ", ".join(map(yaml_num, v)) + "]"


class KalibrNoiseError(InputError):
    """A noise result that does not give kalibr's four noise terms (a term missing or zero)."""


@dataclass(frozen=True)
class KalibrNoise:
    """kalibr's IMU noise terms (continuous time, one value per triad) and the rate it discretises them at.

    From a `bench noise` result: the largest of the three axes of each triad (kalibr takes one value for
    all three; the largest weights no axis more than its noise deserves). A term the record resolves only
    as an upper bound is used as that bound (kalibr's values are meant to be generous) and named in `bounds`.
    """

    update_rate_hz: float
    gyroscope_noise_density: float        # rad/s/sqrt(Hz)   (gyro ARW)
    gyroscope_random_walk: float          # rad/s^2/sqrt(Hz) (gyro RRW)
    accelerometer_noise_density: float    # m/s^2/sqrt(Hz)   (VRW)
    accelerometer_random_walk: float      # m/s^3/sqrt(Hz)   (accelerometer RRW)
    source: str = ""
    bounds: tuple[str, ...] = ()          # "gyro_x rrw", ...: terms that are 2-sigma upper bounds


#: kalibr key -> (channel prefix, noise result term, factor from the result's unit to kalibr's)
KALIBR_NOISE_TERMS = {
    "gyroscope_noise_density": ("gyro", "arw", DEG / 60.0),              # deg/sqrt(h) -> rad/s/sqrt(Hz)
    "gyroscope_random_walk": ("gyro", "rrw", DEG / 3600.0 / 60.0),      # deg/h/sqrt(h) -> rad/s^2/sqrt(Hz)
    "accelerometer_noise_density": ("acc", "vrw", MICRO_G),             # ug/sqrt(Hz) -> m/s^2/sqrt(Hz)
    "accelerometer_random_walk": ("acc", "rrw", MICRO_G / 60.0),        # ug/sqrt(h) -> m/s^3/sqrt(Hz)
}


def kalibr_noise(noise: NoiseResult, source: str = "") -> KalibrNoise:
    """kalibr's noise terms from a noise result (KalibrNoiseError naming the channel and term that lacks)."""
    values: dict[str, float] = {}
    bounds: list[str] = []
    for key, (prefix, term, factor) in KALIBR_NOISE_TERMS.items():
        found = []
        for axis in "xyz":
            channel = noise.channels.get(f"{prefix}_{axis}", {})
            entry = channel.get("terms", {}).get(term)
            if not isinstance(entry, dict) or not entry.get("value", 0) > 0:
                why = str(channel.get("terms_not_resolved", {}).get(term, "not in the file"))
                raise KalibrNoiseError(f"{source or 'the noise result'}: {prefix}_{axis} has no {term} "
                                       f"({why[:160]}); kalibr needs {key} > 0")
            found.append(float(entry["value"]) * factor)
            if entry.get("upper_bound"):
                bounds.append(f"{prefix}_{axis} {term}")
        values[key] = max(found)
    return KalibrNoise(float(noise.rate_hz), source=source, bounds=tuple(bounds), **values)


def to_yaml(c: Compensation, noise: KalibrNoise, rostopic: str = "/imu0") -> str:
    """An IMU file kalibr reads (`ConfigReader.ImuParameters`: top-level `rostopic`, `update_rate` and the
    four noise terms) with the intrinsics of its scale-misalignment model (`model`, `gyroscopes: {M, A,
    C_gyro_i}`, `accelerometers: {M}`).

    kalibr's measurement is in SI units and its `M` dimensionless: `y_topic = M u + bias`. Our model is
    `y = diag(K) E u + diag(K) d` in counts/s, so the topic must carry each raw output divided by its
    scale factor (`scale`, written here): then `M = E` (direction cosines, diagonal about 1) and
    `bias = d` in rad/s and m/s^2. `A` (g-sensitivity) is not in this model (zeros) and `C_gyro_i` is the
    identity (the gyro axes are in `M`). Our `compensation` (u = C (y - b), y in counts/s) rides along.
    """
    ident = _identity(c)
    out = ["# An IMU for kalibr, exported by turntable-bench (see bench.calibration.export)",
           "# topic: each axis' raw output (counts/s) divided by its `scale` below, in rad/s and m/s^2;",
           "# then kalibr's scale-misalignment model holds: y_topic = M u + bias (M dimensionless).",
           f"rostopic: {json.dumps(rostopic)}",
           f"update_rate: {yaml_num(noise.update_rate_hz)}   # Hz, the rate of the noise record"]
    units = {"gyroscope_noise_density": "rad/s/sqrt(Hz)", "gyroscope_random_walk": "rad/s^2/sqrt(Hz)",
             "accelerometer_noise_density": "m/s^2/sqrt(Hz)", "accelerometer_random_walk": "m/s^3/sqrt(Hz)"}
    for key, unit in units.items():
        out.append(f"{key}: {yaml_num(getattr(noise, key))}   # {unit}, the largest of x, y, z")
    out.append(f"noise_source: {json.dumps(noise.source)}")
    if noise.bounds:
        out.append(f"noise_upper_bounds: {json.dumps(list(noise.bounds))}   # 2-sigma bounds, used as values")
    out += ["model: scale-misalignment", "time_offset: 0.0", "T_i_b:"]
    out += [f"  - [{', '.join('1.0' if i == j else '0.0' for j in range(4))}]" for i in range(4)]
    out += [f"{key}: {json.dumps(value)}" for key, value in ident.items() if key != "calibration_software_version"]
    text = "\n".join(out) + "\n"
    g_sensitivity = higher.kalibr_g_sensitivity(c) if c.higher_order is not None else None
    if c.higher_order is not None:
        text += higher.kalibr_left_out(c)
    if c.time_offset is not None:
        text += higher.kalibr_time_offset_comment(c)
    for t, key in ((c.gyro, "gyroscopes"), (c.acc, "accelerometers")):
        text += f"{key}:\n    M:   # dimensionless\n" + _yaml_matrix(t.axes, "      ")
        if t.sensor == "gyro" and g_sensitivity is not None:
            text += ("    A:   # (rad/s)/(m/s^2), g-sensitivity Gg (rows gyros, columns body X Y Z)\n"
                     + _yaml_matrix(g_sensitivity, "      "))
        elif t.sensor == "gyro":
            text += ("    A:   # (rad/s)/(m/s^2), g-sensitivity: not in this model\n"
                     + _yaml_matrix(np.zeros((3, 3)), "      "))
            text += "    C_gyro_i:\n" + _yaml_matrix(np.eye(3), "      ")
        text += f"    bias: {_yaml_vector(t.input_bias)}   # {t.input_unit}\n"
        text += f"    scale: {_yaml_vector(t.scale)}   # {RAW_UNIT} per {t.input_unit}: raw output / scale = topic\n"
        text += f"    bias_counts: {_yaml_vector(t.bias_counts)}   # {RAW_UNIT}\n"
        text += f"    bias_counts_sigma: {_yaml_vector(t.bias_sigma)}\n"
        text += f"    compensation:   # {t.matrix_unit}: u = compensation (y - bias_counts)\n" \
            + _yaml_matrix(t.matrix, "      ")
        text += "    compensation_sigma:\n" + _yaml_matrix(t.matrix_sigma, "      ")
    return text


# -- TOML -----------------------------------------------------------------------------------------

def toml_num(x: float) -> str:
    return repr(float(x)) if math.isfinite(x) else "nan"


def _toml_matrix(m: np.ndarray) -> str:
    return "[\n" + "".join(f"  [{', '.join(map(toml_num, row))}],\n" for row in m) + "]"


def to_toml(c: Compensation) -> str:
    """The JSON document's content as TOML (tomllib reads it back)."""
    version = COMPENSATION_VERSION if c.higher_order is None else higher.HIGHER_ORDER_VERSION
    lines = [f"format = {json.dumps(COMPENSATION_FORMAT)}", f"version = {version}"]
    lines += [f"{key} = {json.dumps(value)}" for key, value in _identity(c).items()]
    for t in c.triads():
        lines += ["", f"[{t.sensor}]", f"measures = {json.dumps(_MEASURES[t.sensor][0])}",
                  f"equation = {json.dumps(EQUATIONS[t.sensor])}", f"raw_unit = {json.dumps(RAW_UNIT)}",
                  f"output_unit = {json.dumps(t.input_unit)}", f"matrix_unit = {json.dumps(t.matrix_unit)}",
                  f"matrix = {_toml_matrix(t.matrix)}", f"matrix_sigma = {_toml_matrix(t.matrix_sigma)}",
                  f"bias_unit = {json.dumps(RAW_UNIT)}",
                  f"bias = [{', '.join(map(toml_num, t.bias_counts))}]",
                  f"bias_sigma = [{', '.join(map(toml_num, t.bias_sigma))}]"]
    if c.higher_order is not None:
        lines += higher.toml_table("higher_order", higher.higher_order_doc(c), toml_num)
    if c.time_offset is not None:
        lines += higher.toml_table("time_offset", higher.time_offset_doc(c), toml_num)
    return "\n".join(lines) + "\n"


#: format name -> writer of the formats that need nothing but the compensation; `yaml` needs noise terms too
FORMATS: dict[str, Callable[[Compensation], str]] = {
    "json": to_json, "csv": to_csv, "c": to_c_header, "toml": to_toml}
FORMAT_NAMES = ("json", "csv", "c", "yaml", "toml")


def export_text(c: Compensation, fmt: str, noise: KalibrNoise | None = None, rostopic: str = "/imu0") -> str:
    """The compensation in format `fmt` (one of `FORMAT_NAMES`); `yaml` (kalibr) needs the IMU's noise
    terms (KalibrNoiseError without them)."""
    if fmt != "yaml":
        return FORMATS[fmt](c)
    if noise is None:
        raise KalibrNoiseError("the kalibr YAML needs the IMU's noise terms: give --noise NAME.noise.json "
                               "(from `bench noise` of a static recording)")
    return to_yaml(c, noise, rostopic)


__all__ = ["COMPENSATION_FORMAT", "COMPENSATION_VERSION", "CSV_COLUMNS", "FORMATS", "FORMAT_NAMES",
           "KALIBR_NOISE_TERMS", "KalibrNoise", "KalibrNoiseError", "c_num", "comment_text", "export_text",
           "kalibr_noise", "to_c_header", "to_csv", "to_json", "to_toml", "to_yaml", "toml_num", "yaml_num"]
