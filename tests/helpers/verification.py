"""verify-default acquired in memory from the simulated IMU, for the verification tests (noise off)."""

from __future__ import annotations

from bench.model.earth import Site
from bench.model.higher_order import HigherOrderTerms
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.extract import Extraction
from schedules import load_builtin

SITE = Site(latitude_deg=30.27)
RATES_DPS = (5.0, 20.0, 60.0)


def acquire_verification(black_box_rad=None, higher_order: HigherOrderTerms | None = None
                         ) -> tuple[Extraction, dict[str, float], ImuCoefficients]:
    """verify-default from the default simulated IMU (an ideal table unless a black box is given; the IMU's
    higher-order truth when given): the extraction, each turn's rate by label, and the IMU's truth."""
    schedule, truth = load_builtin("verify-default"), default_sim_imu()
    positions, rotations, rates = [], [], {}
    for rate in RATES_DPS:
        table = SimTable(SITE, black_box_rad=black_box_rad)
        imu = SimImu(truth, NoiseModel.off(), rate_hz=100.0, higher_order=higher_order)
        p, r = acquire(table, imu, [q.angles_deg for q in schedule.positions] if rate == RATES_DPS[0] else [],
                       [t for t in schedule.rotations if t.rate_dps == rate],
                       AcquisitionTiming(dwell_s=10.0, turn_rate_dps=rate, turn_accel_dps2=20.0))
        for k, o in enumerate(r):
            o.label = f"R{rate:g}-{k}"
            rates[o.label] = rate
        positions += p
        rotations += r
    for k, o in enumerate(positions):
        o.label = f"P{k + 1:02d}"
    return Extraction(positions, rotations, []), rates, truth
