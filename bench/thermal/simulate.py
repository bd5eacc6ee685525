"""A simulated calibration over temperature, in memory, without a chamber.

At each temperature the thermal simulated IMU (`[sim.imu.thermal]`, or `DEMO_THERMAL`)
is soaked at that ambient (its case starts there: the shortcut the chamber + sequencer
will replace), the configured schedules run through the in-memory acquisition
(`bench.sim.acquire`, as `bench evaluate` does), and each run is solved into a result
carrying the IMU's mean case temperature. `fit_thermal_model` then takes those results
as it takes result files from disk.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Sequence

from bench.config.load import BenchConfig
from bench.model.thermal import ImuThermal
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.calibrate import solve
from bench.solve.inputs import bias_stabilities, budget_inputs
from bench.thermal.model import ThermalModel, ThermalPoint, fit_thermal_model
from bench.thermal.truth import attach_sim_truth

#: the thermal behaviour `bench thermal sim` gives the simulated IMU when the configuration has no
#: [sim.imu.thermal]: of the size a navigation-grade FOG IMU shows (bias some 0.002 deg/h and 5 ug per degC,
#: scale factors 5-20 ppm per degC, axes 1 to 2 arcsec per degC), of degrees 0 to 3
DEMO_THERMAL = ImuThermal(reference_c=25.0, time_constant_s=900.0, polynomials={
    "Kg_x": (0.36,), "Kg_y": (-0.25, 0.004), "Kg_z": (0.18,),
    "D0_x": (0.002, 2.0e-5), "D0_y": (-0.0015,), "D0_z": (0.001, 0.0, 2.0e-6),
    "Eg_Yx": (5.0e-6,), "Eg_Xz": (-8.0e-6,),
    "Ka_x": (0.8,), "Ka_y": (-0.6, 0.01), "Ka_z": (0.4,),
    "K0_x": (5.0e-6,), "K0_y": (-4.0e-6, 8.0e-8), "K0_z": (3.0e-6,),
    "Ea_Yx": (6.0e-6,), "Ea_Zy": (-5.0e-6,)})
#: the seed of the temperature at index k is the configuration's seed + k * SEED_STRIDE
SEED_STRIDE = 1000


def timing_of(config: BenchConfig) -> AcquisitionTiming:
    p = config.plan
    return AcquisitionTiming(dwell_s=p.dwell_s, settle_s=p.settle_s, move_rate_dps=p.move_rate_dps,
                             move_accel_dps2=p.move_accel_dps2, turn_rate_dps=p.turn_rate_dps,
                             turn_accel_dps2=p.turn_accel_dps2, rest_s=p.rest_s)


def simulate_point(config: BenchConfig, thermal: ImuThermal, temperature_c: float, seed: int) -> ThermalPoint:
    """One calibration of the simulated IMU soaked at `temperature_c`, solved into a result."""
    soaked = dataclasses.replace(thermal, ambient_c=float(temperature_c), initial_c=float(temperature_c))
    imu = SimImu(config.sim.imu, config.sim.noise, rate_hz=config.imu.rate_hz, seed=seed, thermal=soaked,
                 higher_order=config.sim.higher_order)
    table = SimTable(config.site.site, black_box_rad=config.sim.black_box_rad)
    plan = config.plan
    positions, rotations = acquire(table, imu, [s.angles_deg for s in plan.positions.positions] if plan.positions
                                   else [], list(plan.rotations.rotations) if plan.rotations else [], timing_of(config))
    gyro_dph, acc_ug = bias_stabilities(config, True)
    # the budget's inputs as `bench run --sim` gives them (the table's part: the simulated black box's RMS):
    # without them the table's pointing error in the residuals went unexplained and widened every sigma
    calibration = solve(positions, rotations, config.site.site,
                        gyro_bias_stability=(gyro_dph or 0.0) * DEG_PER_HOUR,
                        acc_bias_stability=(acc_ug or 0.0) * MICRO_G, budget_inputs=budget_inputs(config, True))
    assert imu.case is not None
    summary = imu.case.summary() or {"mean_c": float(temperature_c)}
    temperature: dict[str, Any] = {**summary, "source": "simulated IMU case", "ambient_c": float(temperature_c)}
    truth = thermal.coefficients_at(config.sim.imu, summary["mean_c"])
    identity = config.imu.identity
    result = calibration.to_result({"mode": "simulator (in memory, soaked)", "seed": seed,
                                    "temperature_setpoint_c": float(temperature_c),
                                    "imu": {"model": identity.model, "serial": identity.serial}}, sim_truth=truth)
    result.temperature = temperature
    return ThermalPoint(f"sim {temperature_c:g} degC", temperature, result)


def simulate_thermal(config: BenchConfig, temperatures_c: Sequence[float], *, thermal: ImuThermal | None = None,
                     reference_c: float | None = None, progress=None) -> ThermalModel:
    """Calibrate the simulated IMU at each temperature and fit the thermal model.

    `thermal`: the truth (default: the configuration's [sim.imu.thermal], else `DEMO_THERMAL`);
    `reference_c` of the fitted model: default the truth's. `progress(k, point)` after each temperature.
    """
    truth = thermal or config.sim.thermal or DEMO_THERMAL
    points = []
    for k, temperature_c in enumerate(temperatures_c):
        points.append(simulate_point(config, truth, float(temperature_c), config.sim.seed + k * SEED_STRIDE))
        if progress is not None:
            progress(k, points[-1])
    model = fit_thermal_model(points, truth.reference_c if reference_c is None else reference_c)
    attach_sim_truth(model, truth, config.sim.imu)
    model.run = {"mode": "simulator (in memory, soaked at each temperature)", "seed": config.sim.seed,
                 "seed_stride": SEED_STRIDE, "temperatures_c": [float(t) for t in temperatures_c]}
    return model


__all__ = ["DEMO_THERMAL", "SEED_STRIDE", "simulate_point", "simulate_thermal", "timing_of"]
