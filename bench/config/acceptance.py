"""The configuration's `[acceptance]` section -> `bench.acceptance.limits.AcceptanceLimits`.

Ranges (documented in the README's "Input limits"): per family or coefficient, `min`, `max`
and `nominal` within the family's value range (`VALUE_RANGES`, result units), `min` below
`max` and both or neither; `max_sigma` and `max_change` > 0 and at most the width of that
range; `max_change` needs a `nominal` or `[acceptance] reference`. `max_lost_samples`
0..1e9, `max_residual_sigma` > 0 and <= 1e6. `[acceptance.verification]`: the largest |error|
per verification quantity, > 0 and at most 3600 deg/h, 1e6 ppm, 3600 arcsec or 1e6 ug;
`beyond_uncertainty` "fail" (default: an error beyond its expanded uncertainty fails) or "warn".
`reference` is a result file of at most 1 MiB, read and checked here (so a bad one is refused before anything moves).
"""

from __future__ import annotations

from bench.acceptance.limits import (
    BEYOND_FAIL,
    BEYOND_WARN,
    COEFFICIENT_KEYS,
    VERIFICATION_LIMITS,
    AcceptanceLimits,
    CoefficientLimits,
)
from bench.config.keys import MAX_LOST_SAMPLES, MAX_RESIDUAL_SIGMA, VALUE_RANGES, allowed, integer, optional_number
from bench.config.reader import ConfigError, Table, read_text, show
from bench.errors import InputError
from bench.model.families import FAMILY_INFO, canonical_names, family_of
from bench.model.result import CalibrationResult

ACCEPTANCE_KEYS = allowed("acceptance")


def _limits(t: Table, family: str) -> CoefficientLimits:
    low, high, unit = VALUE_RANGES[family]
    width = high - low
    values = {key: t.number(key, None, ge=low, le=high, unit=unit) for key in ("min", "max", "nominal")}
    for key in ("max_sigma", "max_change"):
        values[key] = t.number(key, None, gt=0, le=width, unit=unit)
    if (values["min"] is None) != (values["max"] is None):
        given = "min" if values["min"] is not None else "max"
        raise t.error(given, "a range needs both min and max")
    if values["min"] is not None and values["max"] is not None and not values["min"] < values["max"]:
        raise t.error("max", f"must be above min ({values['min']:g}), got {values['max']:g}")
    return CoefficientLimits(**values)


def _verification(t: Table) -> tuple[dict[str, float], str]:
    """`[acceptance.verification]`: the limits per quantity, and what an error beyond its U does."""
    v = t.table("verification", allowed("acceptance.verification"))
    out = {}
    for key in VERIFICATION_LIMITS:
        value = optional_number(v, "acceptance.verification", key)
        if value is not None:
            out[key] = value
    return out, v.string("beyond_uncertainty", BEYOND_FAIL, choices=(BEYOND_FAIL, BEYOND_WARN))


def acceptance_limits(t: Table) -> AcceptanceLimits:
    """Parse `[acceptance]` (an empty table: no limits)."""
    families, coefficients = {}, {}
    for key in t.data:
        if key in FAMILY_INFO:
            families[key] = _limits(t.table(key, COEFFICIENT_KEYS), key)
        elif key in canonical_names():
            coefficients[key] = _limits(t.table(key, COEFFICIENT_KEYS), family_of(key))
    reference, reference_name, reference_path = {}, "", ""
    if t.has("reference"):
        path = t.file("reference")
        if not t.is_file("reference", path):
            raise t.error("reference", f"no such result file {show(str(path))}" if not path.exists()
                          else f"{show(str(path))} is not a regular file")
        try:
            result = CalibrationResult.loads(read_text(path, "the reference result file"), str(path))
        except ConfigError as exc:
            raise t.error("reference", exc.message) from exc
        except InputError as exc:   # not a result, not JSON, a number out of range
            raise t.error("reference", str(exc)) from exc
        reference, reference_name, reference_path = result.values(), path.name, str(path)
    limits = AcceptanceLimits(families, coefficients,
                              integer(t, "acceptance", "max_lost_samples"),
                              optional_number(t, "acceptance", "max_residual_sigma"),
                              reference, reference_name, reference_path, *_verification(t))
    if not reference:
        for name in canonical_names():
            merged = limits.for_coefficient(name, family_of(name))
            if merged.max_change is not None and merged.nominal is None:
                own = coefficients.get(name)
                where = name if own is not None and own.max_change is not None else family_of(name)
                raise t.doc.error(t.path + (where, "max_change"),
                                  "needs a nominal value or an [acceptance] reference result file")
    return limits


__all__ = ["ACCEPTANCE_KEYS", "MAX_LOST_SAMPLES", "MAX_RESIDUAL_SIGMA", "VALUE_RANGES", "acceptance_limits"]
