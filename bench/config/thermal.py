"""`[sim.imu.thermal]`: the simulated IMU's temperature dependence (`bench.model.thermal.ImuThermal`).

    [sim.imu.thermal]
    reference_c = 25.0        # the [sim.imu] values hold at this case temperature
    time_constant_s = 600.0   # the case follows its ambient with this first-order time constant
    ambient_c = 25.0          # ambient when nothing drives it (bench run --sim)
    initial_c = 25.0          # case temperature at the start (default: the ambient)
    D0_x = [0.002, 1.0e-5]    # c1, c2 (, c3): display unit per degC, per degC^2, per degC^3

Each polynomial term is bounded so that it moves its coefficient by at most the
coefficient's [sim.imu] range over 100 degC: |c_k| <= range / 100^k.
"""

from __future__ import annotations

from bench.config.keys import (
    MAX_TEMPERATURE_C,
    MAX_TIME_CONSTANT_S,
    MIN_TEMPERATURE_C,
    allowed,
    number,
    optional_number,
)
from bench.config.reader import Table, describe, is_number, number_text, show
from bench.model.families import family_of
from bench.model.thermal import DIAGONAL_NAMES, MAX_THERMAL_DEGREE, THERMAL_NAMES, ImuThermal

#: a polynomial term may move its coefficient by at most its range over this span
_SPAN_C = 100.0
#: the keys of the table (a diagonal is accepted here to be refused with its reason)
THERMAL_KEYS = allowed("sim.imu.thermal")


def sim_thermal(t: Table, family_ranges: dict[str, tuple[float, str]]) -> ImuThermal:
    """The checked [sim.imu.thermal] table; `family_ranges`: family -> (largest |value|, unit)."""
    for key in t.data:
        if key in DIAGONAL_NAMES:
            raise t.error(key, "a direction-cosine diagonal has no polynomial: it follows from the row's "
                               "off-diagonals (unit rows at every temperature)")
    reference_c = number(t, "sim.imu.thermal", "reference_c")
    time_constant_s = number(t, "sim.imu.thermal", "time_constant_s")
    ambient_c = number(t, "sim.imu.thermal", "ambient_c", reference_c)
    initial_c = optional_number(t, "sim.imu.thermal", "initial_c")
    polynomials: dict[str, tuple[float, ...]] = {}
    for name in THERMAL_NAMES:
        if not t.has(name):
            continue
        value = t.get(name)
        high, unit = family_ranges[family_of(name)]
        unit = unit or "1"
        if not isinstance(value, list) or not 1 <= len(value) <= MAX_THERMAL_DEGREE:
            raise t.error(name, f"must be an array of 1 to {MAX_THERMAL_DEGREE} numbers [c1, c2, c3] ({unit} "
                                f"per degC^k), got {describe(value)}"
                          + (f" of {len(value)}" if isinstance(value, list) else ""))
        terms = []
        for k, c in enumerate(value, start=1):
            bound = high / _SPAN_C ** k
            if not is_number(c) or not -bound <= c <= bound:
                got = number_text(c) if is_number(c) else describe(c)
                raise t.doc.error(t.path + (name, k - 1),
                                  f"term c{k} must be a finite number within +-{bound:g} {unit}/degC^{k} "
                                  f"(the coefficient's range over {_SPAN_C:g} degC), got {got}")
            terms.append(float(c))
        polynomials[name] = tuple(terms)
    try:
        return ImuThermal(reference_c, time_constant_s, polynomials, ambient_c, initial_c)
    except ValueError as exc:  # checked above already; a message rather than a traceback if not
        raise t.error(None, f"{exc} ({show(dict(t.data))})") from exc


__all__ = ["MAX_TEMPERATURE_C", "MAX_TIME_CONSTANT_S", "MIN_TEMPERATURE_C", "THERMAL_KEYS", "sim_thermal"]
