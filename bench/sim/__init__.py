"""Simulation world: the true motion of a turntable and the IMU signals it produces."""

from bench.sim.imu import ImuSamples, SimImu
from bench.sim.table import SimTable, TableLimits

__all__ = ["ImuSamples", "SimImu", "SimTable", "TableLimits"]
