"""The six coefficient families of the IMU model, once: names, titles, units.

A coefficient's canonical name is `<family>_<axes>` (`Kg_x`, `Eg_Yx`); its family is
one of `Kg D0 Eg` (gyro scale, bias, axes) or `Ka K0 Ea` (accelerometer scale, bias,
axes). Each family has three sets of units, for three audiences:
- the **result** unit of `*.result.json` and the reports (`counts/s per deg/s`, `deg/h`);
- the **design** unit in which schedule design compares errors across families (`ppm`,
  `arcsec`), with the factor from SI;
- the Monte-Carlo **error** of a family (`bench evaluate`, `bench solve --compare`): one
  number per family, RSS over its axes, scale factors relative.
"""

from __future__ import annotations

from dataclasses import dataclass

from bench.model.units import ARCSEC, DEG, DEG_PER_HOUR, G0

#: the sensors' own axes (a coefficient's last letter) and the body axes (direction-cosine columns)
SENSOR_AXES = ("x", "y", "z")
BODY_AXES = ("X", "Y", "Z")


@dataclass(frozen=True)
class Family:
    """One coefficient family."""

    key: str                  # "Kg"
    sensor: str               # "gyro" | "acc"
    method: str               # the calibration method that determines it: "rotations" | "positions"
    title: str                # "gyro scale"
    result_unit: str          # unit in result files and reports
    result_to_si: float       # result unit -> SI
    design_unit: str          # unit of schedule design's errors
    si_to_design: float       # SI -> design unit
    error_key: str            # name of the family's Monte-Carlo error
    error_title: str          # column title of that error


FAMILY_INFO: dict[str, Family] = {f.key: f for f in (
    Family("Kg", "gyro", "rotations", "gyro scale", "counts/s per deg/s", 1.0 / DEG, "ppm", 1e6,
           "gyro_scale", "gyro scale (rel)"),
    Family("D0", "gyro", "positions", "gyro bias", "deg/h", DEG_PER_HOUR, "deg/h", 1.0 / DEG_PER_HOUR,
           "gyro_bias_dph", "gyro bias deg/h"),
    Family("Eg", "gyro", "rotations", "gyro axes", "1", 1.0, "arcsec", 1.0 / ARCSEC,
           "gyro_axes", "gyro axes"),
    Family("Ka", "acc", "positions", "acc scale", "counts/s per g", 1.0 / G0, "ppm", 1e6,
           "acc_scale", "acc scale (rel)"),
    Family("K0", "acc", "positions", "acc bias", "g", G0, "g", 1.0 / G0,
           "acc_bias_g", "acc bias g"),
    Family("Ea", "acc", "positions", "acc axes", "1", 1.0, "arcsec", 1.0 / ARCSEC,
           "acc_axes", "acc axes"),
)}

#: family -> (result unit, factor result unit -> SI)
RESULT_UNITS = {k: (f.result_unit, f.result_to_si) for k, f in FAMILY_INFO.items()}
#: family -> (design unit, factor SI -> design unit)
DESIGN_UNITS = {k: (f.design_unit, f.si_to_design) for k, f in FAMILY_INFO.items()}
#: family -> title ("gyro scale")
TITLES = {k: f.title for k, f in FAMILY_INFO.items()}
#: Monte-Carlo error key -> its column title
ERROR_TITLES = {f.error_key: f.error_title for f in FAMILY_INFO.values()}
#: the families each method determines, in schedule design's order
POSITION_FAMILIES = ("D0", "K0", "Ka", "Ea")
ROTATION_FAMILIES = ("Kg", "Eg")
#: the Monte-Carlo error keys of each method's families, in schedule design's order (its tables' columns)
POSITION_KEYS = tuple(FAMILY_INFO[k].error_key for k in POSITION_FAMILIES)
ROTATION_KEYS = tuple(FAMILY_INFO[k].error_key for k in ROTATION_FAMILIES)


def family_of(name: str) -> str:
    """The family of a canonical coefficient name: 'Kg_x' -> 'Kg', 'Eg_Yx' -> 'Eg'."""
    return name.split("_", 1)[0]


def canonical_names() -> list[str]:
    """All 30 canonical coefficient names in their canonical order."""
    names: list[str] = []
    for scale, bias, axes in (("Kg", "D0", "Eg"), ("Ka", "K0", "Ea")):
        names += [f"{scale}_{s}" for s in SENSOR_AXES]
        names += [f"{bias}_{s}" for s in SENSOR_AXES]
        names += [f"{axes}_{a}{s}" for s in SENSOR_AXES for a in BODY_AXES]
    return names


__all__ = ["BODY_AXES", "DESIGN_UNITS", "ERROR_TITLES", "FAMILY_INFO", "POSITION_FAMILIES", "POSITION_KEYS",
           "RESULT_UNITS", "ROTATION_FAMILIES", "ROTATION_KEYS", "SENSOR_AXES", "TITLES", "Family", "canonical_names",
           "family_of"]
