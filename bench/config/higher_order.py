"""`[sim.imu.higher_order]`: the simulated IMU's errors beyond the 30 coefficients (bench.model.higher_order).

    [sim.imu.higher_order]
    grade = "tactical-mems"           # start from a preset: "none" (zero), "nav-fog", "tactical-mems"
    gyro_asymmetry_ppm = [0, 0, 0]    # then any key replaces the grade's value
    time_offset_ms = 0.2
"""

from __future__ import annotations

import numpy as np

from bench.config.keys import MAX_TIME_OFFSET_MS, SIM_HIGHER_ORDER_ARRAYS, allowed, declared, optional_number
from bench.config.reader import Table, describe, is_number, number_text
from bench.model.higher_order import GRADE_NAMES, HigherOrderTerms, preset

#: the keys of the table
HIGHER_ORDER_KEYS = allowed("sim.imu.higher_order")


def _array(t: Table, name: str) -> list:
    """The checked array `name`: 3 numbers, or 3 rows of 3 for a "3x3" key."""
    _meaning, high, unit, shape = SIM_HIGHER_ORDER_ARRAYS[name]
    value = t.get(name)
    matrix = shape == "3x3"
    wanted = "3 rows of 3 numbers" if matrix else "3 numbers"
    rows = value if matrix else [value]
    if not isinstance(value, list) or len(value) != 3 or \
            (matrix and not all(isinstance(r, list) and len(r) == 3 for r in value)):
        raise t.error(name, f"must be an array of {wanted} ({unit}), got {describe(value)}")
    for i, row in enumerate(rows):
        for j, x in enumerate(row):
            if not is_number(x) or not -high <= x <= high:
                got = number_text(x) if is_number(x) else describe(x)
                where = t.path + ((name, i, j) if matrix else (name, j))
                raise t.doc.error(where, f"must be a finite number within +-{high:g} {unit}, got {got}")
    return [[float(x) for x in row] for row in value] if matrix else [float(x) for x in value]


def sim_higher_order(t: Table) -> HigherOrderTerms:
    """The checked [sim.imu.higher_order] table: the grade's values with the given keys replacing them."""
    grade = t.string("grade", declared("sim.imu.higher_order", "grade").default, choices=GRADE_NAMES)
    values = preset(grade)
    for name in SIM_HIGHER_ORDER_ARRAYS:
        if t.has(name):
            values[name] = _array(t, name)
    offset = optional_number(t, "sim.imu.higher_order", "time_offset_ms")
    if offset is not None:
        values["time_offset_ms"] = offset
    cross = values.get("acc_cross_ug_per_g2")
    if cross is not None and np.any(np.diag(np.asarray(cross)) != 0.0):
        raise t.error("acc_cross_ug_per_g2", "the diagonal must be 0: an accelerometer's own square is "
                                             "acc_second_order_ug_per_g2")
    return HigherOrderTerms.from_display(values)


__all__ = ["HIGHER_ORDER_KEYS", "MAX_TIME_OFFSET_MS", "sim_higher_order"]
