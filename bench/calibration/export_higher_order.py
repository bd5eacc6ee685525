"""The extended model's families in the exports (issue 30 item 6; `bench.calibration.export` calls these only for
a compensation that holds them, so that a 30-coefficient result exports exactly as before).

Every format carries, per family the result holds, its coefficients in SI (`bench.calibration.higher_order`:
vectors per sensor x, y, z; the g-sensitivity and the cross terms as 3x3 matrices, rows the sensors, columns the
body axes, the cross terms' diagonal zero), their 1-sigma, the scale factors the inverse needs and its equations.
JSON and TOML: a `higher_order` table and `version` 2 (a reader of version 1 would ignore the table and compensate
wrongly); CSV: rows per number; C: arrays and `tb_imu_compensate`, which applies all of it; kalibr's YAML holds
only the g-sensitivity (its `A`), and says in a comment what it leaves out.
"""

from __future__ import annotations

import json
import math
from typing import Any, Callable

import numpy as np

from bench.calibration.compensation import RAW_UNIT, Compensation
from bench.calibration.higher_order import EQUATIONS, MATRIX_TERMS, HigherOrderCompensation
from bench.model.extended import FAMILIES

#: the JSON and TOML version of an export with the extended model's families
HIGHER_ORDER_VERSION = 2
_LAYOUT = {True: "rows: sensors x, y, z; columns: body axes X, Y, Z", False: "per sensor x, y, z"}
_SCALE_UNITS = {"gyro": f"{RAW_UNIT} per rad/s", "acc": f"{RAW_UNIT} per m/s^2"}


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _higher(c: Compensation) -> HigherOrderCompensation:
    assert c.higher_order is not None
    return c.higher_order


def higher_order_doc(c: Compensation) -> dict[str, Any]:
    """The `higher_order` table of the JSON and TOML exports."""
    higher = _higher(c)
    sensors = [t.sensor for t in (c.gyro, c.acc) if any(FAMILIES[n].sensor == t.sensor for n in higher.terms)]
    doc: dict[str, Any] = {"equations": {s: EQUATIONS[s] for s in sensors}}
    for t in (c.gyro, c.acc):
        if t.sensor in sensors:
            doc[f"{t.sensor}_scale"] = t.scale.tolist()
            doc[f"{t.sensor}_scale_unit"] = _SCALE_UNITS[t.sensor]
    doc["terms"] = {name: {"symbol": term.family.key, "title": term.family.title, "unit": term.unit,
                           "layout": _LAYOUT[name in MATRIX_TERMS], "value": term.value.tolist(),
                           "sigma": np.vectorize(_num, otypes=[object])(term.sigma).tolist()}
                    for name, term in higher.terms.items()}
    return doc


#: what the exported time offset is (it is not compensated)
TIME_OFFSET_MEANING = ("the accelerometers sample the motion this much later than the gyros (negative: the gyros are "
                       "later); not compensated: delay the gyro samples by it, or advance the accelerometers'")


def time_offset_doc(c: Compensation) -> dict[str, Any]:
    """The `time_offset` table of the JSON and TOML exports."""
    assert c.time_offset is not None
    value, sigma = c.time_offset
    return {"value": value, "sigma": _num(sigma), "unit": "s", "meaning": TIME_OFFSET_MEANING}


def time_offset_csv_row(c: Compensation) -> list[Any]:
    assert c.time_offset is not None
    value, sigma = c.time_offset
    return ["acc", "time_offset", "", "", repr(float(value)), repr(float(sigma)) if math.isfinite(sigma) else "", "s"]


def time_offset_c_lines(c: Compensation, prefix: str, c_num: Callable[[float], str]) -> str:
    """Two macros (a macro, unlike an unused static const, draws no warning)."""
    assert c.time_offset is not None
    value, sigma = c.time_offset
    return (f"/* s: {TIME_OFFSET_MEANING} */\n#define {prefix}_TIME_OFFSET_S {c_num(value)}\n"
            f"#define {prefix}_TIME_OFFSET_SIGMA_S {c_num(sigma)}\n\n")


def kalibr_time_offset_comment(c: Compensation) -> str:
    """kalibr's `time_offset` is the IMU's clock against its reference sensor, not this offset: a comment says so."""
    assert c.time_offset is not None
    value, sigma = c.time_offset
    return (f"# time_offset above is this IMU's clock against kalibr's reference sensor. The gyro-to-accelerometer "
            f"offset turntable-bench solved, {value!r} s (1-sigma {sigma!r} s), has no place in kalibr's model\n")


def csv_rows(c: Compensation) -> list[list[Any]]:
    """`triad,quantity,row,col,value,sigma,unit` rows: the scale factors, then each family's coefficients (the
    cross terms' zero diagonal is no coefficient and has no row)."""
    higher = _higher(c)
    rows: list[list[Any]] = []
    for t in (c.gyro, c.acc):
        if any(FAMILIES[n].sensor == t.sensor for n in higher.terms):
            rows += [[t.sensor, "scale", i, "", repr(float(t.scale[i])), "", _SCALE_UNITS[t.sensor]] for i in range(3)]
    for name, term in higher.terms.items():
        for index in np.ndindex(term.value.shape):
            if name == "acc_cross" and index[0] == index[1]:
                continue
            sigma = float(term.sigma[index])
            rows.append([term.family.sensor, name, index[0], index[1] if len(index) == 2 else "",
                         repr(float(term.value[index])), repr(sigma) if math.isfinite(sigma) else "", term.unit])
    return rows


# -- C --------------------------------------------------------------------------------------------

def c_comment_lines() -> list[str]:
    """The header comment's lines on `tb_imu_compensate`."""
    return [" *",
            " * With the extended model's terms (TB_IMU_HIGHER_ORDER), use tb_imu_compensate, which takes each",
            " * family's input-equivalent error off the raw outputs before the matrices above (the gyros at f0,",
            " * the accelerometers at w_b, the gyros again at f_b when there is a g-sensitivity):",
            *(f" *   {line}" for s in ("gyro", "acc") for line in EQUATIONS[s].split("; ")),
            " * in SI: rad/s, m/s^2, m; scale factors in counts/s per SI unit; families absent from the",
            " * calibration are absent here (zero)."]


def c_arrays(c: Compensation, prefix: str, array) -> str:
    """The scale factors and every family's values and sigmas as `static const double` arrays."""
    higher = _higher(c)
    text = f"#define {prefix}_HIGHER_ORDER 1\n"
    for t in (c.gyro, c.acc):
        if _has(higher, t.sensor):
            text += array(f"{prefix}_{t.sensor.upper()}_SCALE", t.scale, _SCALE_UNITS[t.sensor])
    for name, term in higher.terms.items():
        what = f"{term.unit}, {_LAYOUT[name in MATRIX_TERMS]}"
        text += array(f"{prefix}_{name.upper()}", term.value, what)
        text += array(f"{prefix}_{name.upper()}_SIGMA", term.sigma, term.unit)
    return text + "\n"


def _has(higher: HigherOrderCompensation, sensor: str) -> bool:
    return any(FAMILIES[n].sensor == sensor for n in higher.terms)


def _c_triad_function(higher: HigherOrderCompensation, prefix: str, sensor: str) -> str:
    """`tb_imu_<sensor>_higher_order`: one triad's error off its raw outputs, then its matrix."""
    name = f"{prefix}_{sensor.upper()}"
    force = "f" if sensor == "gyro" else "f0"
    lines = {
        "gyro_g_sensitivity": f"for (int j = 0; j < 3; ++j) e += {prefix}_GYRO_G_SENSITIVITY[s][j] * f[j];",
        "gyro_asymmetry": f"e += 0.5 * {prefix}_GYRO_ASYMMETRY[s] * fabs(x);",
        "gyro_nonlinearity": f"e += {prefix}_GYRO_NONLINEARITY[s] * x * x;",
        "acc_asymmetry": f"e += 0.5 * {prefix}_ACC_ASYMMETRY[s] * fabs(x);",
        "acc_second_order": f"e += {prefix}_ACC_SECOND_ORDER[s] * x * x;",
        "acc_cross": f"for (int j = 0; j < 3; ++j) e += {prefix}_ACC_CROSS[s][j] * x * f0[j];",
    }
    mine = [n for n in higher.terms if FAMILIES[n].sensor == sensor]
    errors = [lines[n] for n in mine if n in lines]
    uses_input = any(n not in ("gyro_g_sensitivity", "acc_lever_arm") for n in mine)
    uses_force = "gyro_g_sensitivity" in mine or "acc_cross" in mine
    lever = "acc_lever_arm" in mine
    signature = ("const double raw[3], const double f[3], double w_b[3]" if sensor == "gyro"
                 else "const double raw[3], const double f0[3], const double w_b[3], double f_b[3]")
    body = ["    double y[3];"]
    if not uses_force:
        body.append(f"    (void){force};")
    if sensor == "acc" and not lever:
        body.append("    (void)w_b;")
    if lever:
        body.append("    const double w_sq = w_b[0] * w_b[0] + w_b[1] * w_b[1] + w_b[2] * w_b[2];")
    body.append("    for (int s = 0; s < 3; ++s) {")
    if uses_input:
        # at the input less the error at the measured input: one fixed-point step
        body += [f"        const double x0 = (raw[s] - {name}_BIAS[s]) / {name}_SCALE[s];",
                 "        double e = 0.0;",
                 "        for (int pass = 0; pass < 2; ++pass) {",
                 "            const double x = x0 - e;",
                 "            e = 0.0;",
                 *(f"            {line}" for line in errors),
                 "        }"]
    else:
        body += ["        double e = 0.0;", *(f"        {line}" for line in errors)]
    if lever:
        body.append(f"        e -= {prefix}_ACC_LEVER_ARM[s] * (w_sq - w_b[s] * w_b[s]);")
    body += [f"        y[s] = raw[s] - {name}_SCALE[s] * e;", "    }",
             f"    tb_imu_{sensor}_compensate(y, {'w_b' if sensor == 'gyro' else 'f_b'});"]
    return (f"static inline void tb_imu_{sensor}_higher_order({signature})\n{{\n" + "\n".join(body) + "\n}\n\n")


def c_function(c: Compensation, prefix: str) -> str:
    """`tb_imu_compensate`: both triads with the higher-order terms, and `tb_imu_higher_order_sigmas`."""
    higher = _higher(c)
    text = ""
    body = ["    double f0[3];", "    tb_imu_acc_compensate(acc_raw, f0);"]
    if _has(higher, "gyro"):
        text += _c_triad_function(higher, prefix, "gyro")
        body.append("    tb_imu_gyro_higher_order(gyro_raw, f0, w_b);")
    else:
        body.append("    tb_imu_gyro_compensate(gyro_raw, w_b);")
    if _has(higher, "acc"):
        text += _c_triad_function(higher, prefix, "acc")
        body.append("    tb_imu_acc_higher_order(acc_raw, f0, w_b, f_b);")
    else:
        body.append("    tb_imu_acc_compensate(acc_raw, f_b);")
    if "gyro_g_sensitivity" in higher.terms:
        body.append("    tb_imu_gyro_higher_order(gyro_raw, f_b, w_b);")
    sigmas = [f"&{prefix}_{n.upper()}_SIGMA[0]" + ("[0]" if n in MATRIX_TERMS else "") for n in higher.terms]
    choice = "\n         : ".join(f"which == {i} ? {s}" for i, s in enumerate(sigmas[:-1]))
    pick = f"{choice}\n         : {sigmas[-1]}" if choice else f"(void)which, {sigmas[-1]}"
    return (text + "/* body rate w_b (rad/s) and specific force f_b (m/s^2) from raw outputs (counts/s), with the\n"
            " * extended model's terms: the gyros at the linear specific force f0, the accelerometers at their rate,\n"
            " * the gyros again at the compensated force when there is a g-sensitivity */\n"
            "static inline void tb_imu_compensate(const double gyro_raw[3], const double acc_raw[3], double w_b[3],\n"
            "                                     double f_b[3])\n{\n" + "\n".join(body) + "\n}\n\n"
            f"/* the families' 1-sigma arrays in the order {', '.join(higher.terms)} */\n"
            "static inline const double *tb_imu_higher_order_sigmas(int which)\n{\n"
            f"    return {pick};\n}}\n\n")


# -- YAML (kalibr) and TOML -----------------------------------------------------------------------

def kalibr_left_out(c: Compensation) -> str:
    """The one comment line saying what kalibr's model cannot hold ('' when nothing is left out)."""
    left = [n for n in _higher(c).terms if n != "gyro_g_sensitivity"]
    return (f"# kalibr's model has no {', '.join(left)}: left out (the JSON, TOML and C exports carry them)\n"
            if left else "")


def kalibr_g_sensitivity(c: Compensation) -> np.ndarray | None:
    """kalibr's `A` ((rad/s)/(m/s^2), rows gyros, columns body axes): the g-sensitivity, if the result holds it."""
    term = _higher(c).terms.get("gyro_g_sensitivity")
    return None if term is None else term.value


def toml_table(name: str, table: dict[str, Any], number) -> list[str]:
    """`[name]` with the table's values, then its sub-tables as `[name.key]` (strings, numbers and nested lists)."""
    def value(v: Any) -> str:
        if isinstance(v, str):
            return json.dumps(v)
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return number(math.nan if v is None else v)

    lines = ["", f"[{name}]"] + [f"{k} = {value(v)}" for k, v in table.items() if not isinstance(v, dict)]
    for k, v in table.items():
        if isinstance(v, dict):
            lines += toml_table(f"{name}.{k}", v, number)
    return lines


__all__ = ["HIGHER_ORDER_VERSION", "TIME_OFFSET_MEANING", "c_arrays", "c_comment_lines", "c_function", "csv_rows",
           "higher_order_doc", "kalibr_g_sensitivity", "kalibr_left_out", "kalibr_time_offset_comment",
           "time_offset_c_lines", "time_offset_csv_row", "time_offset_doc", "toml_table"]
