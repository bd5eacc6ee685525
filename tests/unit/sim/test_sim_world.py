"""Simulation world: SimTable motion/physics and SimImu signal generation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bench.model import kinematics
from bench.model.earth import Site
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.motion import trapezoid_timing
from bench.model.units import ARCSEC, DEG, DEG_PER_HOUR, MICRO_G
from bench.sim import ImuSamples, SimImu, SimTable, TableLimits

TWO_PI = 2.0 * math.pi


def _check_limits(table: SimTable, t0: float, t1: float, limits: TableLimits, dt: float = 1e-3) -> None:
    times = np.arange(t0, t1 + dt, dt)
    rates = table.frame_rates(times)
    accel = np.diff(rates, axis=0) / dt
    for k in range(3):
        assert np.max(np.abs(rates[:, k])) <= limits.max_rate_dps[k] * DEG * (1 + 1e-9)
        assert np.max(np.abs(accel[:, k])) <= limits.max_accel_dps2[k] * DEG * (1 + 1e-6)
    for frame in kinematics.FRAMES:
        for p in table.pieces(frame):
            assert abs(p.accel) <= limits.max_accel_dps2[kinematics.FRAMES.index(frame)] * DEG * (1 + 1e-12)


# -- table -----------------------------------------------------------------------

def test_limits_validated():
    with pytest.raises(ValueError, match="max_rate_dps"):
        TableLimits(max_rate_dps=(10.0, 0.0, 10.0))
    with pytest.raises(ValueError, match="max_accel_dps2"):
        TableLimits(max_accel_dps2=(10.0, 10.0, -1.0))
    table = SimTable(limits=TableLimits((20.0, 20.0, 30.0), (10.0, 10.0, 20.0)))
    with pytest.raises(ValueError, match="rate_dps"):
        table.move_to(0.0, (10, 10, 10), rate_dps=25.0)
    with pytest.raises(ValueError, match="accel_dps2"):
        table.turn(0.0, "outer", "ccw", 1, 10.0, accel_dps2=11.0)
    with pytest.raises(ValueError):
        table.turn(0.0, "sideways", "ccw", 1, 10.0)
    with pytest.raises(ValueError):
        table.turn(0.0, "inner", "up", 1, 10.0)
    with pytest.raises(ValueError):
        table.set_rate(0.0, "inner", -31.0)
    table.turn(0.0, "inner", "cw", 1, 30.0)   # the inner axis has its own, higher limit
    assert all(len(table.pieces(f)) == 1 for f in ("outer", "middle"))  # failed commands changed nothing


def test_trapezoid_move_limits_end_and_duration():
    limits = TableLimits((20.0, 20.0, 30.0), (10.0, 10.0, 20.0))
    table = SimTable(limits=limits, start_deg=(10.0, 0.0, -5.0))
    target = (100.0, -45.0, 0.3)
    t_end = table.move_to(1.0, target)
    start = np.array([10.0, 0.0, -5.0]) * DEG
    ends = []
    for k, frame in enumerate(kinematics.FRAMES):
        ramp, cruise, _ = trapezoid_timing((target[k] * DEG - start[k]), limits.max_rate_dps[k] * DEG,
                                           limits.max_accel_dps2[k] * DEG)
        end_k = table.pieces(frame)[-1].t0
        assert end_k == pytest.approx(1.0 + 2 * ramp + cruise, abs=1e-9)
        ends.append(end_k)
    assert t_end == max(ends)
    np.testing.assert_array_equal(table.angles(t_end + 1.0), np.array(target) * DEG)
    np.testing.assert_array_equal(table.angles(0.5), start)  # before the move it holds
    assert not table.is_at_rest(2.0) and table.is_at_rest(t_end)
    _check_limits(table, 0.0, t_end + 0.5, limits)


def test_move_commanded_during_a_move_still_ends_at_target():
    limits = TableLimits()
    table = SimTable(limits=limits)
    table.move_to(0.0, (300.0, -200.0, 500.0), rate_dps=(40.0, 40.0, 60.0))
    t_end = table.move_to(3.0, (-30.0, 45.0, 90.0))      # mid-move, all axes moving
    np.testing.assert_array_equal(table.angles(t_end), np.array([-30.0, 45.0, 90.0]) * DEG)
    assert table.is_at_rest(t_end) and not table.is_at_rest(t_end - 0.01)
    _check_limits(table, 0.0, t_end + 0.1, limits)
    # Angle and rate are continuous at the interruption.
    th = table.angles(np.array([3.0 - 1e-7, 3.0 + 1e-7]))
    np.testing.assert_allclose(th[0], th[1], atol=1e-5)


def test_turn_ccw_whole_revolution_and_body_rate():
    site = Site()
    table = SimTable(site=site, start_deg=(0.0, 90.0, 0.0))
    t_end = table.turn(0.0, "outer", "ccw", 1, 10.0)
    assert table.angles(t_end)[0] == -TWO_PI                     # exactly 360 deg lower
    assert table.angles(t_end + 5.0)[0] == -TWO_PI
    ramp, cruise, _ = trapezoid_timing(TWO_PI, 10 * DEG, 50 * DEG)
    assert t_end == pytest.approx(2 * ramp + cruise, abs=1e-9)
    times = np.linspace(ramp + 0.1, ramp + cruise - 0.1, 7)
    np.testing.assert_allclose(table.frame_rates(times)[:, 0], -10 * DEG, rtol=1e-12)
    axes = kinematics.frame_axes_in_body(table.angles(times))[:, 0]
    expected = 10 * DEG * axes + table.attitude(times) @ site.earth_rate_enu
    np.testing.assert_allclose(table.body_rate(times), expected, atol=1e-15)
    # CW whole revolutions from a non-zero start land exactly, too.
    t2 = table.turn(t_end + 1.0, "inner", "cw", 3, 30.0)
    assert table.angles(t2)[2] == 3 * TWO_PI


def test_set_rate_and_stop():
    table = SimTable()
    t_rate = table.set_rate(0.0, "middle", -20.0, accel_dps2=10.0)
    assert t_rate == pytest.approx(2.0)
    assert table.frame_rates(5.0)[1] == pytest.approx(-20 * DEG)
    assert not table.is_at_rest(5.0)
    t_stop = table.stop(5.0)
    assert t_stop == pytest.approx(5.0 + 20.0 / 50.0)
    assert table.is_at_rest(t_stop)
    np.testing.assert_allclose(table.frame_rates(t_stop + 1.0), 0.0)
    # turning while in rate mode first stops, then turns exactly one revolution from rest
    table.set_rate(10.0, "inner", 50.0)
    th_now = table.angles(11.0)[2]
    t_end = table.turn(11.0, "inner", "ccw", 1, 30.0)
    rest = th_now + 0.5 * (50 * DEG) ** 2 / (100 * DEG)
    assert table.angles(t_end)[2] == pytest.approx(rest - TWO_PI, abs=1e-12)


def test_static_ideal_table():
    site = Site()
    table = SimTable(site=site)
    np.testing.assert_allclose(table.body_rate(3.0), site.earth_rate_enu, atol=1e-18)
    np.testing.assert_allclose(table.specific_force(np.array([0.0, 7.0])), [[0, 0, site.gravity]] * 2,
                               atol=1e-15)
    table.move_to(0.0, (0.0, 90.0, 90.0))
    c = table.attitude(100.0)
    np.testing.assert_allclose(c[0], [0.0, -1.0, 0.0], atol=1e-15)   # X south
    assert kinematics.pointing_labels(c) == "S U W"
    assert table.attitude(np.zeros((2, 4))).shape == (2, 4, 3, 3)


def test_black_box_changes_attitude_to_first_order():
    rng = np.random.default_rng(3)
    for level in (20 * ARCSEC, 200 * ARCSEC):
        bb = rng.normal(0.0, level, (3, 3))
        ideal, real = SimTable(), SimTable(black_box_rad=bb)
        for table in (ideal, real):
            table.move_to(0.0, (30.0, 90.0, 270.0))
        diff = real.attitude(60.0) - ideal.attitude(60.0)
        rms = np.sqrt(np.mean(bb ** 2))
        assert 0.2 * rms < np.max(np.abs(diff)) < 6 * rms


# -- IMU --------------------------------------------------------------------------

def test_noise_free_static_outputs_match_model():
    coeffs = default_sim_imu()
    table = SimTable(start_deg=(90.0, 90.0, 0.0))
    s = SimImu(coeffs, rate_hz=200.0).generate(table, 2.0)
    assert len(s) == 400 and s.counter[0] == 0 and s.counter[-1] == 399
    np.testing.assert_allclose(s.time_s, (np.arange(400) + 1) / 200.0)
    np.testing.assert_allclose(s.gyro_rate, np.broadcast_to(coeffs.gyro_output(table.body_rate(1.0)), (400, 3)),
                               rtol=1e-9)
    np.testing.assert_allclose(s.acc_rate, np.broadcast_to(coeffs.acc_output(table.specific_force(1.0)), (400, 3)),
                               rtol=1e-9)


def test_turn_integral_is_exact():
    coeffs = ImuCoefficients.ideal()
    site = Site()
    table = SimTable(site=site)
    imu = SimImu(coeffs, rate_hz=1000.0, start_time_s=-0.5)
    t_end = table.turn(0.00037, "inner", "ccw", 2, 23.7, accel_dps2=37.0)   # kinks off the sample grid
    s = imu.generate(table, t_end + 0.5)
    angle = s.gyro_counts.sum(axis=0) / coeffs.gyro_scale
    duration = s.time_s[-1] + 0.5
    expected_z = 2 * TWO_PI + site.earth_rate_enu[2] * duration
    assert angle[2] == pytest.approx(expected_z, rel=1e-11)


def _noisy() -> NoiseModel:
    return NoiseModel(gyro_arw_deg_rt_h=0.05, gyro_bias_instability_dph=0.02, acc_vrw_ug_rt_hz=30.0,
                      acc_bias_instability_ug=5.0, correlation_time_s=2.0, quantise=True)


def test_chunked_generation_equals_one_shot():
    def make():
        table = SimTable()
        table.turn(0.3, "outer", "ccw", 1, 60.0)
        return table, SimImu(default_sim_imu(), _noisy(), rate_hz=500.0, seed=7)

    table, imu = make()
    one = imu.generate(table, 12.0)
    table, imu = make()
    parts = [imu.generate(table, t) for t in (0.0, 0.0031, 1.7, 1.7, 6.25, 12.0)]
    joined = ImuSamples.concatenate(parts)
    for name in ("counter", "time_s", "gyro_counts", "acc_counts"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(one, name))
    assert len(parts[0]) == 0 and len(parts[3]) == 0


def test_seed_determinism_and_independent_streams():
    table = SimTable()

    def gen(noise, seed):
        return SimImu(default_sim_imu(), noise, rate_hz=100.0, seed=seed).generate(table, 5.0)

    a, b, c = gen(_noisy(), 1), gen(_noisy(), 1), gen(_noisy(), 2)
    np.testing.assert_array_equal(a.gyro_counts, b.gyro_counts)
    np.testing.assert_array_equal(a.acc_counts, b.acc_counts)
    assert not np.array_equal(a.gyro_counts, c.gyro_counts)
    assert not np.array_equal(a.acc_counts, c.acc_counts)
    # Switching the gyro noise off leaves the accelerometer noise unchanged.
    no_q = NoiseModel(0.05, 0.02, 30.0, 5.0, 2.0, False)
    only_acc = NoiseModel(0.0, 0.0, 30.0, 5.0, 2.0, False)
    np.testing.assert_array_equal(gen(no_q, 4).acc_counts, gen(only_acc, 4).acc_counts)


def test_white_noise_statistics():
    coeffs = default_sim_imu()
    noise = NoiseModel(gyro_arw_deg_rt_h=0.01, gyro_bias_instability_dph=0.0, acc_vrw_ug_rt_hz=20.0,
                       acc_bias_instability_ug=0.0, correlation_time_s=300.0, quantise=False)
    rate = 200.0
    table = SimTable(start_deg=(0.0, 90.0, 45.0))
    s = SimImu(coeffs, noise, rate_hz=rate, seed=11).generate(table, 200.0)
    gyro_sigma = coeffs.gyro_scale * 0.01 * DEG / 60.0 * math.sqrt(rate)
    acc_sigma = coeffs.acc_scale * 20.0 * MICRO_G * math.sqrt(rate)
    gyro_dev = s.gyro_rate - coeffs.gyro_output(table.body_rate(1.0))
    acc_dev = s.acc_rate - coeffs.acc_output(table.specific_force(1.0))
    np.testing.assert_allclose(gyro_dev.std(axis=0), gyro_sigma, rtol=0.05)
    np.testing.assert_allclose(acc_dev.std(axis=0), acc_sigma, rtol=0.05)
    assert np.all(np.abs(gyro_dev.mean(axis=0)) < 5 * gyro_sigma / math.sqrt(len(s)))


def test_gauss_markov_bias_statistics():
    coeffs = default_sim_imu()
    noise = NoiseModel(gyro_arw_deg_rt_h=0.0, gyro_bias_instability_dph=0.01, acc_vrw_ug_rt_hz=0.0,
                       acc_bias_instability_ug=3.0, correlation_time_s=0.5, quantise=False)
    table = SimTable()
    gyro, acc = [], []
    for seed in range(4):
        s = SimImu(coeffs, noise, rate_hz=100.0, seed=seed).generate(table, 150.0)
        gyro.append((s.gyro_rate - coeffs.gyro_output(table.body_rate(1.0))) / coeffs.gyro_scale)
        acc.append((s.acc_rate - coeffs.acc_output(table.specific_force(1.0))) / coeffs.acc_scale)
    gyro_std = np.sqrt(np.mean(np.concatenate(gyro) ** 2))
    acc_std = np.sqrt(np.mean(np.concatenate(acc) ** 2))
    assert gyro_std == pytest.approx(0.01 * DEG_PER_HOUR, rel=0.2)
    assert acc_std == pytest.approx(3.0 * MICRO_G, rel=0.2)
    # correlated: lag-1 autocorrelation near exp(-dt/tau)
    g = np.concatenate(gyro)[:, 0]
    assert np.corrcoef(g[1:], g[:-1])[0, 1] == pytest.approx(math.exp(-0.01 / 0.5), abs=0.02)


def test_quantisation_carries_the_remainder():
    coeffs = default_sim_imu()
    noisy = NoiseModel(0.05, 0.02, 30.0, 5.0, 2.0, quantise=True)
    smooth = NoiseModel(0.05, 0.02, 30.0, 5.0, 2.0, quantise=False)
    table = SimTable()
    table.turn(1.0, "middle", "cw", 1, 90.0)
    q_imu, f_imu = SimImu(coeffs, noisy, rate_hz=400.0, seed=5), SimImu(coeffs, smooth, rate_hz=400.0, seed=5)
    q = ImuSamples.concatenate([q_imu.generate(table, t) for t in (2.0, 3.3, 8.0)])
    f = f_imu.generate(table, 8.0)
    for qc, fc in ((q.gyro_counts, f.gyro_counts), (q.acc_counts, f.acc_counts)):
        np.testing.assert_array_equal(qc, np.round(qc))
        assert np.max(np.abs(np.cumsum(qc, axis=0) - np.cumsum(fc, axis=0))) < 1.0
        assert not np.array_equal(qc, fc)


def test_counter_wraps():
    imu = SimImu(ImuCoefficients.ideal(), rate_hz=1000.0, start_time_s=-(2 ** 32 - 2) / 1000.0)
    imu._done = 2 ** 32 - 3   # jump close to the wrap without generating 4e9 samples
    s = imu.generate(SimTable(), 0.002)
    np.testing.assert_array_equal(s.counter, [2 ** 32 - 3, 2 ** 32 - 2, 2 ** 32 - 1, 0, 1][: len(s)])
    assert s.counter.dtype == np.int64
