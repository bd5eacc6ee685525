"""Whose timing a run's duration estimates take (`bench.plan.retime.TimingProfile`), from its configuration.

The compiled plan is the same for every path that runs it (bench run, the TUI, a resumed log);
only its estimates depend on who runs it:

- the simulator (`bench run --sim`, `bench check-table --sim`): the simulated table moves and
  turns every axis at its own acceleration limit (the sequencer commands no acceleration), a move
  ends at the sequencer's next in-position poll (half a poll period on average), the simulated
  chamber's air follows its setpoint with its time constant and heating and cooling limits
  (`bench.sim.chamber.ChamberPhysics`), the IMU's case follows the air with `[sim.imu.thermal]
  time_constant_s` (no thermal IMU: its temperature stays, the soak waits for the air alone);
- hardware: `[plan] move_accel_dps2` and `turn_accel_dps2` (within `[table.limits]`) and
  `move_overhead_s`, the chamber's air at `[plan] ramp_c_per_min` (2 degC/min without a ramp) and
  an IMU case lagging the air with `NOMINAL_IMU_TIME_CONSTANT_S`: no key says a real IMU's
  thermal time constant, and ten minutes is that of a small IMU in its mount (the simulated
  IMU's default). A soak's estimate is only as good as that guess.
"""

from __future__ import annotations

from typing import Sequence

from bench.config.load import BenchConfig
from bench.plan.retime import SoakModel, TimingProfile, retime
from bench.plan.steps import Step
from bench.plan.thermal import NOMINAL_AIR_RATE_C_PER_MIN, START_C
from bench.run.runner import SIM_OPTIONS
from bench.sim.chamber import ChamberPhysics
from bench.sim.table import TableLimits

#: the thermal time constant of a real IMU's case assumed by the soak estimates (no key says it), s
NOMINAL_IMU_TIME_CONSTANT_S = 600.0


def _sim_soak(config: BenchConfig) -> SoakModel:
    air = ChamberPhysics()
    thermal = config.sim.thermal
    if thermal is None:
        return SoakModel(None, air.time_constant_s, air.max_heat_c_per_min, air.max_cool_c_per_min, None,
                         air.ambient_c, air.ambient_c)
    start_imu_c = thermal.initial_c if thermal.initial_c is not None else thermal.ambient_c
    return SoakModel(None, air.time_constant_s, air.max_heat_c_per_min, air.max_cool_c_per_min,
                     thermal.time_constant_s, air.ambient_c, start_imu_c)


def timing_profile(config: BenchConfig, sim: bool) -> TimingProfile:
    """The profile of the controller and chamber that run `config`'s plan (`sim`: the simulator's)."""
    if sim:
        accel = TableLimits().max_accel_dps2        # the simulated world's table (bench.sim.world)
        overhead_s = float(SIM_OPTIONS["move_poll_s"]) / 2.0
        return TimingProfile("the simulated controller", accel, accel, overhead_s, overhead_s, _sim_soak(config))
    plan, axes = config.plan, config.table.limits.axes
    outer, middle, inner = (min(plan.move_accel_dps2, axis.max_accel_dps2) for axis in axes)
    turn = float(plan.turn_accel_dps2)
    ramp = plan.thermal.ramp_c_per_min if plan.thermal is not None else None
    soak = SoakModel(ramp or NOMINAL_AIR_RATE_C_PER_MIN, 0.0, imu_time_constant_s=NOMINAL_IMU_TIME_CONSTANT_S,
                     start_air_c=START_C, start_imu_c=START_C)
    return TimingProfile("the configured profile ([plan])", (outer, middle, inner), (turn, turn, turn),
                         plan.move_overhead_s, 0.0, soak)


def estimates(config: BenchConfig, steps: Sequence[Step], sim: bool) -> tuple[float, ...]:
    """What each of `steps` (`config`'s plan, compiled) will take when run on the simulator (`sim`) or hardware, s."""
    return retime(steps, timing_profile(config, sim))


__all__ = ["NOMINAL_IMU_TIME_CONSTANT_S", "estimates", "timing_profile"]
