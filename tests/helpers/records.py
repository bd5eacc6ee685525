"""Real result files made fast: the in-memory acquisition (`bench.sim.acquire`) and the solver, no sequencer."""

from __future__ import annotations

import datetime as dt
from pathlib import Path

from bench import __version__
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.calibrate import solve
from schedules import load_builtin

SITE = Site(30.27)
FAST = AcquisitionTiming(dwell_s=2.0, settle_s=0.5, move_rate_dps=60, move_accel_dps2=30, turn_rate_dps=30,
                         turn_accel_dps2=20, rest_s=0.5)
_POSITIONS = [p.angles_deg for p in load_builtin("optimal-24").positions]
_TURNS = list(load_builtin("optimal-5s6r").rotations)


def drifted_imu(years: float, d0_drift_dph_per_year: float = 0.0) -> ImuCoefficients:
    """The default simulated IMU whose gyro x bias D0_x drifted by `d0_drift_dph_per_year` for `years`."""
    values = default_sim_imu().to_canonical()
    values["D0_x"] += d0_drift_dph_per_year * years
    return ImuCoefficients.from_canonical(values)


def write_result(out_dir: Path, serial: str, when: dt.datetime, seed: int, *, imu: ImuCoefficients | None = None,
                 model: str = "simulated FOG IMU", operator: str = "tester") -> Path:
    """Simulate, solve and save one calibration of `serial` started at `when` (UTC); returns the result path."""
    imu = imu or default_sim_imu()
    positions, rotations = acquire(SimTable(SITE), SimImu(imu, NoiseModel(), rate_hz=100.0, seed=seed),
                                   _POSITIONS, _TURNS, FAST)
    run_id = f"{when:%Y%m%dT%H%M%SZ}-{serial.lower()}-{seed}"
    finished = when + dt.timedelta(minutes=30)
    run = {"run_id": run_id, "mode": "simulator", "operator": operator, "software_version": __version__,
           "state": "done", "log": f"{run_id}.mcap", "positions": "optimal-24", "rotations": "optimal-5s6r",
           "finished_utc": finished.strftime("%Y-%m-%dT%H:%M:%SZ"), "imu": {"model": model, "serial": serial},
           "site": {"latitude_deg": SITE.latitude_deg, "height_m": 0.0, "local_g": None}}
    result = solve(positions, rotations, SITE).to_result(run, sim_truth=imu)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{run_id}.result.json"
    result.save(path)
    return path
