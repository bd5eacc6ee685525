"""One calibration per temperature from a thermal run's log, and the thermal model fitted to them.

A thermal plan (`bench.plan.thermal`) labels each temperature block's units "T<k>-<unit>"
and opens the block with a `set_temperature` step whose event carries the setpoint; the
observations of the whole log are extracted once and told apart by their block, each
block is solved on its own (`solve_extraction`) into a result whose `temperature` section
is the IMU's temperature over that block's observation windows (from the decoded
samples), and `fit_thermal_model` fits every coefficient against those temperatures.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from bench.errors import InputError
from bench.log.reader import RunLog
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients
from bench.model.thermal import ImuThermal
from bench.plan.steps import thermal_block
from bench.solve.budget import BudgetInputs
from bench.solve.extract import Extraction, finished_observation_steps
from bench.solve.from_logs import extract_from_logs, solve_extraction
from bench.thermal.model import ThermalModel, ThermalPoint, fit_thermal_model
from bench.thermal.truth import attach_sim_truth
from drivers.imu.layout import ImuLayout


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
            step = event.data.get("step") if event.kind == "step_started" else None
            if isinstance(step, dict) and step.get("kind") == "set_temperature":
                try:
                    out[int(step["temperature_index"])] = float(step["setpoint_c"])
                except (KeyError, TypeError, ValueError):
                    continue
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
            first, last = int(finished.data["counter_first"]), int(finished.data["counter_last"])
            a, b = np.searchsorted(counter, first), np.searchsorted(counter, last, side="right")
            values.append(samples.temperature_c[a:b])
    temps = np.concatenate(values) if values else np.zeros(0)
    temps = temps[np.isfinite(temps)]
    if not len(temps):
        return None
    return {"mean_c": float(temps.mean()), "min_c": float(temps.min()), "max_c": float(temps.max()),
            "samples": int(len(temps)), "source": "IMU frames (the temperature's observation windows)"}


def solve_blocks(logs: list[RunLog], site: Site, layout: ImuLayout, rate_hz: float, *, run: dict[str, Any],
                 gyro_bias_stability_dph: float | None = None, acc_bias_stability_ug: float | None = None,
                 sim_imu: ImuCoefficients | None = None, sim_thermal: ImuThermal | None = None,
                 still_open: frozenset[str] = frozenset(),
                 budget: BudgetInputs | None = None) -> tuple[list[BlockSolution], list[str]]:
    """A calibration per temperature block of the logs (ThermalRunError when a block cannot be placed in
    temperature) and the logs' damage lines. `run` goes into every result, with the block's own entries."""
    extraction, _, damage = extract_from_logs(logs, site, layout, rate_hz, still_open=still_open)
    setpoints = _setpoints(logs)
    blocks = sorted({b for b in (thermal_block(o.label) for o in extraction.positions + extraction.rotations)
                     if b is not None})
    out = []
    for k in blocks:
        part = Extraction([o for o in extraction.positions if thermal_block(o.label) == k],
                          [o for o in extraction.rotations if thermal_block(o.label) == k],
                          [p for p in extraction.problems if f"T{k}-" in p])
        calibration = solve_extraction(part, site, gyro_bias_stability_dph=gyro_bias_stability_dph,
                                       acc_bias_stability_ug=acc_bias_stability_ug, budget=budget)
        temperature = _block_temperature(logs, layout, rate_hz, k)
        if temperature is None:
            raise ThermalRunError(f"temperature block T{k}: the IMU reported no temperature in its observations")
        setpoint = setpoints.get(k)
        truth = (sim_thermal.coefficients_at(sim_imu, temperature["mean_c"])
                 if sim_thermal is not None and sim_imu is not None else sim_imu)
        result = calibration.to_result({**run, "temperature_block": k, "temperature_setpoint_c": setpoint},
                                       sim_truth=truth)
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


__all__ = ["BlockSolution", "ThermalRunError", "fit_blocks", "nearest_block", "solve_blocks"]
