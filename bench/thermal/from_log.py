"""One calibration per temperature from a thermal run's log, and the thermal model fitted to them.

A thermal plan (`bench.plan.thermal`) labels each temperature block's units "T<k>-<unit>"
and opens the block with a `set_temperature` step whose event carries the setpoint; the
observations of the whole log are extracted once and told apart by their block, each
block is solved on its own (`solve_extraction`) into a result whose `temperature` section
is the IMU's temperature over that block's observation windows (from the decoded
samples), and `fit_thermal_model` fits every coefficient against those temperatures.

`solve_thermal` is that whole computation for a configuration (its bias stabilities, budget
inputs and, on the simulator, truth), shared by `bench run` and `bench solve`;
`bench.report.thermal.write_thermal_files` writes its per-temperature results and the model
with its reports.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from bench.config.thermal import MAX_TEMPERATURE_C, MIN_TEMPERATURE_C
from bench.errors import InputError
from bench.log.events import StepStarted, finished_observation_steps
from bench.log.reader import RunLog
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients
from bench.model.run_section import RunInfo
from bench.model.thermal import ImuThermal
from bench.plan.steps import MAX_BLOCK_DIGITS, thermal_block
from bench.solve.budget import BudgetInputs
from bench.solve.extract import Extraction
from bench.solve.from_logs import extract_from_logs, solve_extraction
from bench.solve.inputs import bias_stabilities, budget_inputs
from bench.solve.methods import SolverError
from bench.thermal.model import ThermalModel, ThermalPoint, fit_thermal_model
from bench.thermal.truth import attach_sim_truth
from drivers.imu.layout import ImuLayout

#: the reference temperature of a thermal model fitted to a hardware run, degC
THERMAL_REFERENCE_C = 25.0


class ThermalRunError(InputError):
    """A thermal run's log that cannot give a calibration per temperature."""


@dataclass
class BlockSolution:
    """The calibration of one temperature block."""

    temperature_index: int
    setpoint_c: float | None
    point: ThermalPoint
    extraction: Extraction


def _setpoints(logs: list[RunLog]) -> dict[int, float]:
    """Block -> setpoint from the `set_temperature` steps' events."""
    out: dict[int, float] = {}
    for log in logs:
        for event in log.events:
            step = event.step if isinstance(event, StepStarted) else None
            if isinstance(step, dict) and step.get("kind") == "set_temperature":
                index, setpoint = step.get("temperature_index"), step.get("setpoint_c")
                # a log is hostile: a block number is a small integer, a setpoint a temperature in range (a
                # comparison, never a conversion: 10**400 has no float, NaN is in no range)
                if (type(index) is int and 1 <= index < 10 ** MAX_BLOCK_DIGITS
                        and isinstance(setpoint, (int, float)) and not isinstance(setpoint, bool)
                        and MIN_TEMPERATURE_C <= setpoint <= MAX_TEMPERATURE_C):
                    out[index] = float(setpoint)
    return out


def _block_temperature(logs: list[RunLog], layout: ImuLayout, rate_hz: float, k: int) -> dict[str, Any] | None:
    """The IMU's temperature over block k's observation windows: mean, min, max, samples."""
    values = []
    for log in logs:
        samples, _ = log.imu_samples(layout, rate_hz)
        counter = np.asarray(samples.counter, dtype=np.int64)
        for unit, (_, finished) in finished_observation_steps(log.events).items():
            if thermal_block(unit) != k:
                continue
            assert finished.window is not None          # a finished observation step has one
            first, last = finished.window.first, finished.window.last
            a, b = np.searchsorted(counter, first), np.searchsorted(counter, last, side="right")
            values.append(samples.temperature_c[a:b])
    temps = np.concatenate(values) if values else np.zeros(0)
    temps = temps[np.isfinite(temps)]
    if not len(temps):
        return None
    return {"mean_c": float(temps.mean()), "min_c": float(temps.min()), "max_c": float(temps.max()),
            "samples": int(len(temps)), "source": "IMU frames (the temperature's observation windows)"}


def solve_blocks(logs: list[RunLog], site: Site, layout: ImuLayout, rate_hz: float, *, run: RunInfo,
                 gyro_bias_stability_dph: float | None = None, acc_bias_stability_ug: float | None = None,
                 sim_imu: ImuCoefficients | None = None, sim_thermal: ImuThermal | None = None,
                 still_open: frozenset[str] = frozenset(), budget: BudgetInputs | None = None,
                 extracted: tuple[Extraction, list[str]] | None = None) -> tuple[list[BlockSolution], list[str]]:
    """A calibration per temperature block of the logs (ThermalRunError when a block cannot be placed in
    temperature) and the logs' damage lines. `run` goes into every result, with the block's own entries.
    `extracted`: the logs' extraction and damage lines when the caller has them (`extract_from_logs`)."""
    if extracted is None:
        extraction, _, damage = extract_from_logs(logs, site, layout, rate_hz, still_open=still_open)
    else:
        extraction, damage = extracted
    setpoints = _setpoints(logs)
    blocks = sorted({b for b in (thermal_block(o.label) for o in extraction.positions + extraction.rotations)
                     if b is not None})
    out = []
    for k in blocks:
        part = Extraction([o for o in extraction.positions if thermal_block(o.label) == k],
                          [o for o in extraction.rotations if thermal_block(o.label) == k],
                          [p for p in extraction.problems if p.unit is not None and thermal_block(p.unit) == k])
        calibration = solve_extraction(part, site, gyro_bias_stability_dph=gyro_bias_stability_dph,
                                       acc_bias_stability_ug=acc_bias_stability_ug, budget=budget)
        temperature = _block_temperature(logs, layout, rate_hz, k)
        if temperature is None:
            raise ThermalRunError(f"temperature block T{k}: the IMU reported no temperature in its observations")
        setpoint = setpoints.get(k)
        truth = (sim_thermal.coefficients_at(sim_imu, temperature["mean_c"])
                 if sim_thermal is not None and sim_imu is not None else sim_imu)
        block_run = replace(run, extra={**run.extra, "temperature_block": k, "temperature_setpoint_c": setpoint})
        result = calibration.to_result(block_run, sim_truth=truth)
        result.temperature = {**temperature, "setpoint_c": setpoint}
        label = f"T{k} ({setpoint:g} degC)" if setpoint is not None else f"T{k}"
        out.append(BlockSolution(k, setpoint, ThermalPoint(label, result.temperature, result), part))
    return out, damage


def fit_blocks(blocks: list[BlockSolution], reference_c: float, *, sim_imu: ImuCoefficients | None = None,
               sim_thermal: ImuThermal | None = None) -> ThermalModel:
    """The thermal model of the blocks' calibrations (with the simulated truth when there is one)."""
    model = fit_thermal_model([b.point for b in blocks], reference_c)
    if sim_thermal is not None and sim_imu is not None:
        attach_sim_truth(model, sim_thermal, sim_imu)
    return model


def nearest_block(blocks: list[BlockSolution], temperature_c: float) -> BlockSolution:
    """The block whose IMU temperature is nearest `temperature_c` (the run's headline calibration)."""
    return min(blocks, key=lambda b: abs(b.point.temperature_c - temperature_c))


@dataclass
class ThermalSolution:
    """A thermal run solved: a calibration per temperature, the model (None below two temperatures), the block
    nearest the reference (the run's own result) and the logs' damage lines."""

    blocks: list[BlockSolution]
    damage: list[str]
    model: ThermalModel | None
    head: BlockSolution
    reference_c: float


def solve_thermal(logs: list[RunLog], site: Site, layout: ImuLayout, rate_hz: float, config, sim: bool, *,
                  run: RunInfo, still_open: frozenset[str] = frozenset(),
                  extracted: tuple[Extraction, list[str]] | None = None) -> ThermalSolution:
    """Every temperature block of the logs solved with what `config` (None: nothing) says beyond the data, as
    a plain run's solve is, and the thermal model fitted (SolverError when no block has an observation).
    `extracted` as for `solve_blocks`."""
    stability = bias_stabilities(config, sim) if config is not None else (None, None)
    truth_imu = config.sim.imu if sim and config is not None else None
    truth_thermal = config.sim.thermal if sim and config is not None else None
    blocks, damage = solve_blocks(logs, site, layout, rate_hz, run=run, gyro_bias_stability_dph=stability[0],
                                  acc_bias_stability_ug=stability[1], sim_imu=truth_imu, sim_thermal=truth_thermal,
                                  still_open=still_open, extracted=extracted,
                                  budget=budget_inputs(config, sim) if config is not None else None)
    if not blocks:
        raise SolverError("the thermal run has no finished observation at any temperature")
    reference_c = truth_thermal.reference_c if truth_thermal is not None else THERMAL_REFERENCE_C
    model = None
    if len({round(b.point.temperature_c, 3) for b in blocks}) >= 2:
        model = fit_blocks(blocks, reference_c, sim_imu=truth_imu, sim_thermal=truth_thermal)
    return ThermalSolution(blocks, damage, model, nearest_block(blocks, reference_c), reference_c)


__all__ = ["THERMAL_REFERENCE_C", "BlockSolution", "ThermalRunError", "ThermalSolution", "fit_blocks",
           "nearest_block", "solve_blocks", "solve_thermal"]
