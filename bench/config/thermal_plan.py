"""`[plan] temperatures_c` and `[plan.soak]`: a calibration at each chamber temperature (`bench.plan.thermal`).

    [plan]
    temperatures_c = [-20.0, 0.0, 25.0, 50.0]   # chamber setpoints, in the order visited
    ramp_c_per_min = 2.0                        # optional: the chamber's ramp (default: the controller's)
    [plan.soak]                                 # when the IMU counts as soaked (its own temperature)
    rate_c_per_min = 0.05                       # IMU temperature rate below this ...
    stable_min = 10.0                           # ... for this long, once the chamber air is at the setpoint
    max_soak_min = 240.0                        # longer than this: a fault (chamber made safe, table stopped)
    chamber_tolerance_c = 1.0                   # "the air is at the setpoint"
    rate_window_s = 60.0                        # the rate is the least-squares slope over this window

A thermal plan needs a [chamber] and every temperature within its limits (checked by
`check_against_chamber` once the [chamber] section is read).
"""

from __future__ import annotations

from bench.config.keys import MAX_TEMPERATURE_C, MAX_TEMPERATURES, MIN_TEMPERATURE_C, allowed, number, optional_number
from bench.config.reader import Table, describe, is_number, number_text
from bench.plan.thermal import SoakCriterion, ThermalPlan
from drivers.chamber import ChamberLimits

PLAN_THERMAL_KEYS = ("temperatures_c", "ramp_c_per_min", "soak")
SOAK_KEYS = allowed("plan.soak")


def thermal_plan(t: Table) -> ThermalPlan | None:
    """The checked temperatures and soak of a [plan] table; None when it has no `temperatures_c`."""
    if not t.has("temperatures_c"):
        for key in ("ramp_c_per_min", "soak"):
            if t.has(key):
                raise t.error(key, "only with plan.temperatures_c (a calibration at each chamber temperature)")
        return None
    value = t.get("temperatures_c")
    if not isinstance(value, list) or not 1 <= len(value) <= MAX_TEMPERATURES:
        raise t.error("temperatures_c", f"must be an array of 1 to {MAX_TEMPERATURES} temperatures in degC, "
                                        f"got {describe(value)}")
    temperatures: list[float] = []
    for k, c in enumerate(value):
        if not is_number(c) or not MIN_TEMPERATURE_C <= c <= MAX_TEMPERATURE_C:
            got = number_text(c) if is_number(c) else describe(c)
            raise t.doc.error(t.path + ("temperatures_c", k), f"must be a temperature from {MIN_TEMPERATURE_C:g} to "
                                                               f"{MAX_TEMPERATURE_C:g} degC, got {got}")
        if any(abs(float(c) - seen) < 1e-6 for seen in temperatures):
            raise t.doc.error(t.path + ("temperatures_c", k), f"{number_text(c)} degC is listed twice")
        temperatures.append(float(c))
    ramp = optional_number(t, "plan", "ramp_c_per_min")
    s = t.table("soak", SOAK_KEYS)
    default = SoakCriterion()
    rate = number(s, "plan.soak", "rate_c_per_min")
    stable_min = number(s, "plan.soak", "stable_min")
    max_soak_min = number(s, "plan.soak", "max_soak_min", max(default.max_soak_min, stable_min))
    tolerance = number(s, "plan.soak", "chamber_tolerance_c")
    window = number(s, "plan.soak", "rate_window_s", min(default.rate_window_s, stable_min * 60.0))
    if stable_min > max_soak_min:
        raise s.error("max_soak_min", f"must be at least stable_min ({stable_min:g} min), got {max_soak_min:g}")
    if window > stable_min * 60.0:
        raise s.error("rate_window_s", f"must be at most stable_min ({stable_min * 60.0:g} s), got {window:g}")
    soak = SoakCriterion(rate, stable_min, max_soak_min, tolerance, window)
    return ThermalPlan(tuple(temperatures), soak, ramp)


def check_against_chamber(t: Table, plan: ThermalPlan, limits: ChamberLimits | None) -> None:
    """A thermal plan needs a [chamber] whose limits take every temperature and the ramp."""
    if limits is None:
        raise t.error("temperatures_c", "a calibration over temperature needs a [chamber] section (the chamber "
                                        "that sets each temperature; url = \"sim\" for the simulated one)")
    for k, c in enumerate(plan.temperatures_c):
        if not limits.min_setpoint_c <= c <= limits.max_setpoint_c:
            raise t.doc.error(t.path + ("temperatures_c", k),
                              f"{c:g} degC is outside the chamber limits [{limits.min_setpoint_c:g}, "
                              f"{limits.max_setpoint_c:g}] degC (chamber.limits)")
    if plan.ramp_c_per_min is not None and plan.ramp_c_per_min > limits.max_ramp_c_per_min:
        raise t.error("ramp_c_per_min", f"{plan.ramp_c_per_min:g} degC/min exceeds the chamber limit "
                                        f"{limits.max_ramp_c_per_min:g} degC/min (chamber.limits.max_ramp_c_per_min)")


__all__ = ["PLAN_THERMAL_KEYS", "SOAK_KEYS", "check_against_chamber", "thermal_plan"]
