"""The solver on data sampled from the simulated world (table + IMU at a realistic rate)."""

import math

import numpy as np
import pytest

from bench.model.earth import Site
from bench.model.families import canonical_names
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.observations import turn_axis_in_body, turn_earth_integral
from bench.model.units import ARCSEC, DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.calibrate import solve
from schedules import load_builtin
from tests.helpers.solver import assert_recovered

SITE = Site(30.27)
FAST = AcquisitionTiming(dwell_s=5.0, settle_s=1.0, move_rate_dps=60, move_accel_dps2=30, turn_rate_dps=20,
                         turn_accel_dps2=10, rest_s=0.5)


def _steps(pos_name, rot_name):
    return ([p.angles_deg for p in load_builtin(pos_name).positions], list(load_builtin(rot_name).rotations))


@pytest.mark.parametrize("pos_name, rot_name", [("optimal-24", "optimal-5s6r"),
                                                ("traditional-12", "traditional-3s6r")])
def test_sampled_noise_free_world_recovers_truth(pos_name, rot_name):
    imu = default_sim_imu()
    positions, rotations = acquire(SimTable(SITE), SimImu(imu, rate_hz=100.0), *_steps(pos_name, rot_name), FAST)
    values, _ = solve(positions, rotations, SITE).values_and_sigmas()
    assert_recovered(values, imu)


def test_turn_integral_brute_force_matches_closed_form():
    """Integrate a simulated 1 kHz turn sample by sample; compare with the closed form."""
    imu = default_sim_imu()
    bb = np.random.default_rng(2).normal(0, 60 * ARCSEC, (3, 3))
    table = SimTable(SITE, black_box_rad=bb, start_deg=(0, 90, 90))
    sim = SimImu(imu, rate_hz=1000.0)
    t_cmd = 0.5
    stop = table.turn(t_cmd, "outer", "cw", 2, rate_dps=20.0, accel_dps2=8.0)
    t_end = math.ceil((stop + 0.5) * 1000) / 1000
    samples = sim.generate(table, t_end)
    counts = samples.gyro_counts.sum(axis=0)
    # closed form: M (d 2 pi N u + int w_earth) + Kg D0 T, with the true (black-box) axis
    u = turn_axis_in_body((0, 90, 90), 0, black_box=bb)
    earth = turn_earth_integral(SITE, (0, 90, 90), 0, table.pieces("outer"), 0.0, t_end, black_box=bb)
    closed = imu.gyro_matrix @ (-2 * 2 * math.pi * u + earth) + imu.gyro_scale * imu.gyro_bias * t_end
    assert len(samples) == round(t_end * 1000)
    assert np.allclose(counts, closed, rtol=0, atol=1e-9 * np.abs(closed).max())
    # and the Earth term matters at this precision: leaving it out breaks the agreement
    without_earth = imu.gyro_matrix @ (-2 * 2 * math.pi * u) + imu.gyro_scale * imu.gyro_bias * t_end
    assert np.abs(counts - without_earth).max() > 1e3 * 1e-9 * np.abs(closed).max()


@pytest.mark.slow
def test_noise_on_truth_within_three_sigma():
    """Over repeated seeds, >= 99 % of the coefficients lie within 3 sigma of the truth."""
    imu = default_sim_imu()
    noise = NoiseModel()
    timing = AcquisitionTiming(dwell_s=30.0)
    pos, rot = _steps("optimal-24", "optimal-5s6r")
    z = []
    for seed in range(8):
        positions, rotations = acquire(SimTable(SITE), SimImu(imu, noise, rate_hz=100.0, seed=seed), pos, rot,
                                       timing)
        cal = solve(positions, rotations, SITE, gyro_bias_stability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                    acc_bias_stability=noise.acc_bias_instability_ug * MICRO_G)
        values, sigmas = cal.values_and_sigmas()
        truth = imu.to_canonical()
        z += [(values[n] - truth[n]) / sigmas[n] for n in canonical_names()]
    z = np.array(z)
    assert np.all(np.isfinite(z))
    assert np.mean(np.abs(z) < 3) >= 0.99
    # and the uncertainties are not wildly inflated either
    assert 0.5 < np.std(z) < 1.5


def test_sampled_observations_carry_sample_statistics():
    imu = default_sim_imu()
    pos, rot = _steps("optimal-24", "optimal-5s6r")
    positions, rotations = acquire(SimTable(SITE), SimImu(imu, NoiseModel(), rate_hz=100.0, seed=1),
                                   pos[:2], rot[:1], FAST)
    obs = positions[0]
    assert obs.sample_count == 500 and obs.duration_s == pytest.approx(5.0)
    assert np.all(obs.gyro_std > 0) and np.all(obs.standard_error("acc") > 0)
    assert rotations[0].duration_s > 360 / 20
    assert rotations[0].earth_integral_rad is not None
