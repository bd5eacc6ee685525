"""The extended model's coefficient families: the higher-order terms a solve can estimate beyond the 30 (issue 30).

`[model] terms` names the families (`TERMS`); each family's coefficients have canonical names
`<key>_<axes>` as the 30 do (`Gg_Xx`: gyro x's sensitivity to the specific force along body X). The model
(`bench.model.higher_order` simulates it) in input units, per sensor s:

    gyro s:   F_s = Kg_s (Eg_s . w + D0_s + Gg_s . f + Ag_s/2 |u_s| + Ng_s u_s^2)
    accel s:  J_s = Ka_s (Ea_s . f_s + K0_s + Aa_s/2 |a_s| + Qa_s a_s^2 + sum_j!=s Ca_js a_s f_j)
    f_s = f + w x (w x r_s) + dw/dt x r_s,  La_s = r_s . e_s  (accelerometer s's own-axis lever arm)

    Dt: the accelerometers sample the motion Dt later than the gyros (one number; `bench.solve.time_offset`)

Only the lever arm's component along the sensor's own axis is a coefficient: a turn about a body axis moves an
accelerometer's output by `-w^2 r_ss` (its other components need turns about tilted axes).
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.units import DEG, DEG_PER_HOUR, G0, MICRO_G

PPM = 1e-6


@dataclass(frozen=True)
class ExtendedFamily:
    """One family of the extended model."""

    term: str            # the `[model] terms` name
    key: str             # canonical name prefix
    sensor: str          # "gyro" | "acc"
    title: str
    result_unit: str
    result_to_si: float
    names: tuple[str, ...]


def _per_sensor(key: str) -> tuple[str, ...]:
    return tuple(f"{key}_{s}" for s in SENSOR_AXES)


def _matrix(key: str, off_diagonal: bool = False) -> tuple[str, ...]:
    return tuple(f"{key}_{a}{s}" for s in SENSOR_AXES for j, a in enumerate(BODY_AXES)
                 if not (off_diagonal and SENSOR_AXES[j] == s))


FAMILIES: dict[str, ExtendedFamily] = {f.term: f for f in (
    ExtendedFamily("gyro_g_sensitivity", "Gg", "gyro", "gyro g-sensitivity", "deg/h per g", DEG_PER_HOUR / G0,
                   _matrix("Gg")),
    ExtendedFamily("gyro_asymmetry", "Ag", "gyro", "gyro scale-factor asymmetry", "ppm", PPM, _per_sensor("Ag")),
    ExtendedFamily("gyro_nonlinearity", "Ng", "gyro", "gyro scale-factor nonlinearity", "ppm per deg/s", PPM / DEG,
                   _per_sensor("Ng")),
    ExtendedFamily("acc_asymmetry", "Aa", "acc", "accelerometer scale-factor asymmetry", "ppm", PPM,
                   _per_sensor("Aa")),
    ExtendedFamily("acc_second_order", "Qa", "acc", "accelerometer second order", "ug/g^2", MICRO_G / G0 ** 2,
                   _per_sensor("Qa")),
    ExtendedFamily("acc_cross", "Ca", "acc", "accelerometer cross terms", "ug/g^2", MICRO_G / G0 ** 2,
                   _matrix("Ca", off_diagonal=True)),
    ExtendedFamily("acc_lever_arm", "La", "acc", "accelerometer lever arm (own axis)", "mm", 1e-3,
                   _per_sensor("La")),
    # one number for the unit: the accelerometers' delay behind the gyros (bench.solve.time_offset)
    ExtendedFamily("time_offset", "Dt", "acc", "gyro-to-accelerometer time offset", "ms", 1e-3, ("Dt",)),
)}
#: families of one coefficient for the whole unit (no sensor axis in its name)
SCALAR_TERMS = ("time_offset",)
#: the `[model] terms` names, in solve order
TERMS = tuple(FAMILIES)
#: the families the windows' means and integrals show: all but the time offset, which needs the turns' timing
MEAN_TERMS = tuple(t for t in TERMS if t not in SCALAR_TERMS)
#: canonical prefix -> family
BY_KEY = {f.key: f for f in FAMILIES.values()}
#: every extended coefficient name, in canonical order
EXTENDED_NAMES = tuple(n for f in FAMILIES.values() for n in f.names)
#: prefix -> (result unit, factor result unit -> SI), as `bench.model.families.RESULT_UNITS`
EXTENDED_RESULT_UNITS = {f.key: (f.result_unit, f.result_to_si) for f in FAMILIES.values()}


def family_of_name(name: str) -> ExtendedFamily | None:
    """The extended family of a coefficient name, None for one of the 30."""
    return BY_KEY.get(name.split("_", 1)[0])


__all__ = ["BY_KEY", "EXTENDED_NAMES", "EXTENDED_RESULT_UNITS", "FAMILIES", "MEAN_TERMS", "PPM", "SCALAR_TERMS",
           "TERMS", "ExtendedFamily", "family_of_name"]
