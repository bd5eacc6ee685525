"""The verification run: its plan, its simulated world, its checks and its files.

A verification runs the `[plan] verification` schedule (default `verify-default`) with the
configuration's timing and limits, recorded to its own log like any run. On the
simulator the world's seed is the configuration's plus one, so that its IMU noise is not
the calibration run's, and its table is the calibration's: the black-box angles its result
recorded (`run.sim`), else the configuration's (the same when the configuration is). Its
errors (`bench.verify.errors`) are checked against `[acceptance.verification]`: each
limited quantity gives one check per error, failing when |error| exceeds the limit; and,
unless `beyond_uncertainty = "warn"`, each error against its expanded uncertainty U.
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from bench import __version__
from bench.acceptance.limits import BEYOND_FAIL
from bench.acceptance.verdict import VERIFICATION, Check, Verdict, max_check
from bench.config.load import BenchConfig
from bench.log.names import output_path
from bench.model.result import CalibrationResult
from bench.model.units import ARCSEC
from bench.plan.compiler import CompiledPlan, compile_plan
from bench.plan.steps import TurnStep
from bench.report.markdown import md_text
from bench.verify.errors import EXTENDED_QUANTITIES, QUANTITIES, Verification
from schedules import Schedule, load_builtin

DEFAULT_SCHEDULE = "verify-default"
VERIFICATION_FORMAT = "turntable-bench/verification"
VERIFICATION_VERSION = 1


def verification_schedule(config: BenchConfig) -> Schedule:
    """`[plan] verification`, else the shipped `verify-default`."""
    return config.plan.verification or load_builtin(DEFAULT_SCHEDULE)


def sim_table_record(config: BenchConfig) -> dict[str, Any]:
    """What a simulated run's result records of its world (`run.sim`): the seed and the table's black-box
    angles (arcsec, rows o0, m0, i0), so that its verification runs on the same table."""
    return {"seed": config.sim.seed, "black_box_arcsec": (np.asarray(config.sim.black_box_rad) / ARCSEC).tolist()}


def recorded_sim_table(calibration: CalibrationResult | None) -> np.ndarray | None:
    """The black-box angles (3, 3) rad a simulated calibration recorded (`sim_table_record`), else None."""
    sim = calibration.run.sim if calibration is not None else None
    angles = sim.get("black_box_arcsec") if isinstance(sim, dict) else None
    try:
        table = np.array(angles, dtype=float) * ARCSEC
    except (TypeError, ValueError):
        return None
    return table if table.shape == (3, 3) and np.all(np.isfinite(table)) else None


def verification_config(config: BenchConfig, calibration: CalibrationResult | None = None) -> BenchConfig:
    """The configuration a verification runs with: the verification schedule as its plan's positions and
    rotations (what the run log records), and on the simulator a world seeded anew (seed + 1) on the table
    `calibration` recorded (`recorded_sim_table`; else the configuration's)."""
    schedule = verification_schedule(config)
    plan = dataclasses.replace(config.plan, positions=schedule if schedule.positions else None,
                               rotations=schedule if schedule.rotations else None)
    table = recorded_sim_table(calibration)
    sim = dataclasses.replace(config.sim, seed=(config.sim.seed + 1) % 2 ** 32,
                              black_box_rad=config.sim.black_box_rad if table is None else table)
    return dataclasses.replace(config, plan=plan, sim=sim)


def verification_plan(config: BenchConfig) -> CompiledPlan:
    """The compiled plan of a `verification_config` (PlanError when it does not fit the table's limits)."""
    plan = config.plan
    return compile_plan(plan.positions, plan.rotations, plan, limits=config.table.limits, order=plan.order)


def turn_rates(plan: CompiledPlan) -> dict[str, float]:
    """Each turn unit's rate, deg/s."""
    return {step.unit: float(step.rate_dps) for step in plan.steps if isinstance(step, TurnStep)}


def verification_checks(verification: Verification, limits: dict[str, float],
                        beyond_uncertainty: str = BEYOND_FAIL) -> list[Check]:
    """One check per error of a limited quantity (`[acceptance.verification]`), and with `beyond_uncertainty`
    "fail" one per error against its expanded uncertainty U (an error beyond U fails; "warn": only marked)."""
    checks = []
    for error in verification.errors:
        limit = limits.get(error.quantity)
        if limit is None:
            continue
        checks.append(max_check(f"verify {error.name}", error.value, limit, error.unit, f"U = {error.uncertainty:.3g}",
                                signed=True, kind=VERIFICATION))
    for quantity in limits:
        if not verification.of(quantity):
            checks.append(Check(f"verify {QUANTITIES[quantity][1]}", None, limits[quantity], QUANTITIES[quantity][0],
                                False, math.inf, "not determined by the verification plan"
                                + (" (checked for a result with higher-order families)"
                                   if quantity in EXTENDED_QUANTITIES else ""), kind=VERIFICATION))
    if beyond_uncertainty == BEYOND_FAIL:
        checks += [max_check(f"verify {e.name} vs U", e.value, e.uncertainty, e.unit, "U, k = 2", signed=True,
                             kind=VERIFICATION) for e in verification.errors]
    return checks


def verification_document(verification: Verification, checks: list[Check], *, run_id: str, calibration: str,
                          schedule: str, log: str) -> dict[str, Any]:
    return {"format": VERIFICATION_FORMAT, "version": VERIFICATION_VERSION, "verdict": Verdict(checks).to_json(),
            "run_id": run_id, "calibration": calibration, "schedule": schedule, "log": log,
            "software_version": __version__, **verification.to_json()}


def verification_markdown(verification: Verification, checks: list[Check], *, run_id: str, calibration: str,
                          schedule: str) -> str:
    lines = [f"# Verification {md_text(run_id)}", "",
             f"**Verification verdict: {md_text(Verdict(checks).headline())}**", "",
             f"- **calibration**: {md_text(calibration)}", f"- **schedule**: {md_text(schedule)}", "",
             "Errors after compensation with the calibration, on data the calibration did not use; U is the "
             "expanded uncertainty (k = 2: the verification data's noise, the calibration's own uncertainty and "
             f"the turntable's pointing error when known). {md_text(verification.table_line())}.",
             "", "| error | value | U (k = 2) | table part of U (k = 2) | unit | within U |",
             "|---|---|---|---|---|---|"]
    for e in verification.errors:
        lines.append(f"| {md_text(e.name)} | {e.value:.4g} | {e.uncertainty:.3g} | {e.table_part:.3g} | {e.unit} | "
                     f"{'yes' if e.within_uncertainty else '**no**'} |")
    if verification.notes:
        lines += ["", "Notes:"] + [f"- {md_text(n)}" for n in verification.notes]
    if checks:
        lines += ["", "| check | result |", "|---|---|"]
        lines += [f"| {md_text(c.describe())} | {'pass' if c.passed else '**FAIL**'} |" for c in checks]
    return "\n".join(lines) + "\n"


def write_verification(out_dir: str | Path, run_id: str, verification: Verification, checks: list[Check], *,
                       calibration: str, schedule: str, log: str) -> tuple[Path, Path]:
    """`<run-id>.verify.json` and `<run-id>.verify.md` in `out_dir`."""
    json_path = output_path(Path(out_dir), f"{run_id}.verify.json")
    md_path = output_path(Path(out_dir), f"{run_id}.verify.md")
    document = verification_document(verification, checks, run_id=run_id, calibration=calibration, schedule=schedule,
                                     log=log)
    json_path.write_text(json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    md_path.write_text(verification_markdown(verification, checks, run_id=run_id, calibration=calibration,
                                             schedule=schedule), encoding="utf-8")
    return json_path, md_path


def format_errors(verification: Verification) -> str:
    """The errors as terminal lines: name, value +- U, unit."""
    width = max((len(e.name) for e in verification.errors), default=10)
    lines = [f"{e.name:<{width}}  {e.value:>+11.4g} +- {e.uncertainty:<9.3g} {e.unit}"
             + ("" if e.within_uncertainty else "  (beyond U)") for e in verification.errors]
    return "\n".join(lines + [f"note: {n}" for n in verification.notes] + [f"note: {verification.table_line()}"])


__all__ = ["DEFAULT_SCHEDULE", "VERIFICATION_FORMAT", "format_errors", "recorded_sim_table", "sim_table_record",
           "turn_rates", "verification_checks",
           "verification_config", "verification_document", "verification_markdown", "verification_plan",
           "verification_schedule", "write_verification"]
