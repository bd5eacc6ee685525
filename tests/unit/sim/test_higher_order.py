"""The simulated IMU's higher-order terms (bench.model.higher_order, issue 30) against closed-form expectations:
a static position's g-sensitivity, a rate step's asymmetry, the size effect (centripetal and tangential) at a
known rate and lever arm, the time offset on a rate ramp; off means bit for bit the 30-coefficient outputs."""

from __future__ import annotations

import numpy as np
import pytest

from bench.config.load import ConfigError, parse_config
from bench.model.earth import Site
from bench.model.higher_order import GRADES, HigherOrderTerms, preset
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.units import DEG, DEG_PER_HOUR, G0, MICRO_G
from bench.sim.imu import SimImu
from bench.sim.table import SimTable, TableLimits
from tests.helpers.run import api_run, config_text, load_json, only_file

RATE_HZ = 1000.0
IDEAL = ImuCoefficients.ideal()
NO_NOISE = NoiseModel.off()
LIMITS = TableLimits((400.0, 400.0, 400.0), (2000.0, 2000.0, 2000.0))


def make_table(latitude_deg: float = 30.0) -> SimTable:
    return SimTable(Site(latitude_deg=latitude_deg), limits=LIMITS)


def outputs(table: SimTable, t_end: float, terms: HigherOrderTerms | None, imu: ImuCoefficients = IDEAL,
            noise: NoiseModel = NO_NOISE):
    """(sample end times, gyro rates, accel rates) in counts/s, noise-free unless told."""
    samples = SimImu(imu, noise, rate_hz=RATE_HZ, seed=3, higher_order=terms).generate(table, t_end)
    return samples.time_s, samples.gyro_rate, samples.acc_rate


def difference(table: SimTable, t_end: float, terms: HigherOrderTerms, imu: ImuCoefficients = IDEAL):
    """The outputs with the terms minus those without, in input units (rad/s, m/s^2), and the sample mid-times."""
    times, gyro, acc = outputs(table, t_end, terms, imu)
    _, gyro0, acc0 = outputs(table, t_end, None, imu)
    return times - 0.5 / RATE_HZ, (gyro - gyro0) / imu.gyro_scale, (acc - acc0) / imu.acc_scale


def test_all_zero_terms_leave_every_output_bit_for_bit():
    table = make_table()
    table.move_to(0.5, [30.0, 60.0, -45.0], rate_dps=50.0, accel_dps2=100.0)
    noise = NoiseModel()
    plain = outputs(table, 5.0, None, default_sim_imu(), noise)
    zero = outputs(table, 5.0, HigherOrderTerms(), default_sim_imu(), noise)
    for a, b in zip(plain, zero):
        assert np.array_equal(a, b)


def test_a_static_position_sees_the_g_sensitivity_times_gravity():
    table = make_table(30.0)
    table.move_to(0.0, [0.0, 90.0, 0.0])            # body axes no longer ENU: gravity off the Z column
    sensitivity = np.array([[8.0, -3.0, 2.0], [2.5, 10.0, -4.0], [-2.0, 3.5, 9.0]])   # deg/h per g
    terms = HigherOrderTerms.from_display({"gyro_g_sensitivity_dph_per_g": sensitivity})
    rest = 10.0
    _mid, gyro, acc = difference(table, rest + 1.0, terms)
    force_g = table.specific_force(rest) / G0                          # body specific force, g
    assert np.linalg.norm(force_g) == pytest.approx(table.site.gravity / G0)
    expected_dph = sensitivity @ force_g                               # closed form: G f, deg/h
    settled = gyro[int(rest * RATE_HZ):] / DEG_PER_HOUR
    np.testing.assert_allclose(settled, np.broadcast_to(expected_dph, settled.shape), rtol=1e-9, atol=1e-9)
    assert np.abs(expected_dph).max() > 5.0                            # a term of the size configured
    assert np.all(acc == 0.0)                                          # the accelerometers do not see it


def test_a_rate_step_shows_the_asymmetry_as_different_scale_factors():
    asymmetry_ppm = 200.0
    terms = HigherOrderTerms.from_display({"gyro_asymmetry_ppm": [0.0, 0.0, asymmetry_ppm]})
    rate_dps = 100.0

    def z_gyro_at(body_rate_dps: float) -> float:
        table = make_table(0.0)     # no Earth rate along body Z: the input is the table's rate
        # a positive (paper: clockwise) inner rate is a negative rate about body Z (model.md#frame-rotations)
        table.set_rate(0.0, "inner", -body_rate_dps, accel_dps2=1000.0)
        assert table.body_rate(0.5)[2] / DEG == pytest.approx(body_rate_dps, abs=1e-9)
        _t, gyro, _acc = outputs(table, 1.0, terms)
        return float(np.mean(gyro[500:, 2]))        # steady after 0.1 s of ramp

    kg = IDEAL.gyro_scale[2] * DEG                   # counts/s per deg/s
    k_plus = (z_gyro_at(rate_dps) - z_gyro_at(0.0)) / rate_dps / kg
    k_minus = (z_gyro_at(-rate_dps) - z_gyro_at(0.0)) / -rate_dps / kg
    # closed form: K (1 + A/2) for a positive input, K (1 - A/2) for a negative one
    assert k_plus == pytest.approx(1.0 + 0.5e-6 * asymmetry_ppm, rel=1e-10)
    assert k_minus == pytest.approx(1.0 - 0.5e-6 * asymmetry_ppm, rel=1e-10)
    assert (k_plus - k_minus) / 1e-6 == pytest.approx(asymmetry_ppm, rel=1e-5)


def test_the_nonlinearity_is_quadratic_in_rate():
    terms = HigherOrderTerms.from_display({"gyro_nonlinearity_ppm_per_dps": [0.0, 0.0, 0.5]})
    table = make_table(0.0)
    table.set_rate(0.0, "inner", -80.0, accel_dps2=1000.0)
    _mid, gyro, _acc = difference(table, 1.0, terms)
    # closed form: N u^2 = 0.5 ppm/(deg/s) * 80 deg/s * 80 deg/s, the same sign for either direction
    assert np.mean(gyro[500:, 2]) / DEG == pytest.approx(0.5e-6 * 80.0 * 80.0, rel=1e-9)


def test_the_size_effect_is_the_centripetal_force_at_a_known_rate_and_lever_arm():
    lever_mm = 10.0
    terms = HigherOrderTerms.from_display({"acc_lever_arm_mm": [[lever_mm, 0.0, 0.0], [0.0] * 3, [0.0] * 3]})
    table = make_table(0.0)
    table.set_rate(0.0, "inner", 100.0, accel_dps2=1000.0)
    _mid, gyro, acc = difference(table, 1.0, terms)
    omega = 100.0 * DEG
    expected = -omega ** 2 * lever_mm * 1e-3          # toward the centre: -w^2 r, 3.05e-2 m/s^2 = 3.1 mg
    np.testing.assert_allclose(acc[500:, 0], expected, rtol=1e-6)
    assert abs(expected) / MICRO_G == pytest.approx(3110.0, rel=0.01)   # the 3.1 mg at 100 deg/s, 1 cm
    assert np.all(acc[:, 1:] == 0.0) and np.all(gyro == 0.0)          # only accelerometer x has an arm


def test_the_size_effect_has_the_tangential_term_while_the_rate_ramps():
    lever_mm, accel_dps2 = 20.0, 50.0
    terms = HigherOrderTerms.from_display({"acc_lever_arm_mm": [[0.0] * 3, [lever_mm, 0.0, 0.0], [0.0] * 3]})
    table = make_table(0.0)
    table.set_rate(0.1, "inner", -100.0, accel_dps2=accel_dps2)      # 2 s of ramp from t = 0.1, CCW about +Z
    _mid, _gyro, acc = difference(table, 3.0, terms)
    # accelerometer y sits on body X: (dw/dt Z) x (r X) = alpha r along Y during the ramp, 0 when steady
    expected = accel_dps2 * DEG * lever_mm * 1e-3
    np.testing.assert_allclose(acc[200:2000, 1], expected, rtol=1e-6)
    np.testing.assert_allclose(acc[2200:, 1], 0.0, atol=1e-9)                 # rounding of the difference


def test_the_time_offset_delays_the_accelerometers_on_a_rate_ramp():
    table = make_table(30.0)
    table.move_to(0.0, [0.0, 90.0, 0.0])                               # inner axis horizontal: gravity turns
    table.set_rate(1.0, "inner", 100.0, accel_dps2=50.0)               # the ramp: 2 s
    offset_samples = 2
    terms = HigherOrderTerms(time_offset_s=offset_samples / RATE_HZ)
    mid, gyro, acc = difference(table, 4.0, terms)
    _t, _g, acc_plain = outputs(table, 4.0, None)
    _t, _g, acc_late = outputs(table, 4.0, terms)
    # exactly the plain outputs two samples earlier, away from the motion's kinks (a kink is split only where the
    # table has it, not where the delayed accelerometers see it)
    kinks = table.piece_starts()
    away = np.all(np.abs(mid[:, None] - kinks[None, :]) > 0.01, axis=1)
    away[:offset_samples] = False
    later = np.nonzero(away)[0]
    np.testing.assert_allclose(acc_late[later], acc_plain[later - offset_samples], rtol=0, atol=1e-7)
    # first order: f(t - tau) - f(t) = tau w x f for gravity turning in body axes, 1.7 mg per ms at 100 deg/s
    w, f = table.body_rate_and_specific_force(mid)
    closed = terms.time_offset_s * np.cross(w, f)
    steady = mid > 3.1
    np.testing.assert_allclose(acc[steady], closed[steady], rtol=0, atol=2e-3 * np.abs(closed).max())
    assert np.abs(closed[steady]).max() / MICRO_G == pytest.approx(
        2.0 * 100.0 * DEG * table.site.gravity / MICRO_G * 1e-3, rel=1e-3)
    assert np.all(gyro == 0.0)                                         # the gyros are the time reference


def test_a_negative_time_offset_delays_the_gyros_instead():
    table = make_table(30.0)
    table.move_to(0.0, [0.0, 90.0, 0.0])
    table.set_rate(1.0, "inner", 100.0, accel_dps2=50.0)
    plain = outputs(table, 4.0, None)
    late_gyros = outputs(table, 4.0, HigherOrderTerms(time_offset_s=-2.0 / RATE_HZ))
    assert np.array_equal(late_gyros[2], plain[2])                     # the accelerometers are the reference
    middle = slice(1500, 2500)                                         # inside the ramp, away from its kinks
    np.testing.assert_allclose(late_gyros[1][middle], plain[1][1498:2498], rtol=1e-12)
    assert not np.allclose(late_gyros[1][middle], plain[1][middle], rtol=0, atol=1e-3)


def test_second_order_and_cross_terms_at_a_static_position():
    terms = HigherOrderTerms.from_display({"acc_second_order_ug_per_g2": [0.0, 0.0, 150.0],
                                           "acc_cross_ug_per_g2": [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                                                                   [40.0, -30.0, 0.0]],
                                           "acc_asymmetry_ppm": [0.0, 0.0, 400.0]})
    table = make_table(30.0)
    table.move_to(0.0, [0.0, 35.0, 20.0])
    _mid, _gyro, acc = difference(table, 10.0, terms)
    f = table.specific_force(9.0) / G0                                 # g
    a = f[2]
    expected_ug = 150.0 * a * a + 40.0 * a * f[0] - 30.0 * a * f[1] + 0.5 * 400.0 * abs(a)   # ppm * g = ug
    np.testing.assert_allclose(acc[9000:, 2] / MICRO_G, expected_ug, rtol=1e-9)


def test_the_presets_are_the_configured_grades():
    for grade in GRADES:
        terms = HigherOrderTerms.from_display(preset(grade))
        assert terms.enabled and terms.has_lever_arms and terms.time_offset_s > 0
    mems, fog = (HigherOrderTerms.from_display(preset(g)) for g in ("tactical-mems", "nav-fog"))
    assert np.abs(mems.gyro_g_sensitivity).max() > 100 * np.abs(fog.gyro_g_sensitivity).max()
    assert not HigherOrderTerms.from_display(preset("none")).enabled


CONFIG = """\
format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.0
[table]
url = "sim"
dialect = "scpi"
[imu]
interface = "virtual"
channel = "higher-order-test"
rate_hz = 100.0
[plan]
positions = "optimal-24"
rotations = "optimal-5s6r"
"""


def test_the_configuration_takes_a_grade_and_overrides_and_is_off_by_default():
    assert parse_config(CONFIG).sim.higher_order is None
    config = parse_config(CONFIG + '[sim.imu.higher_order]\ngrade = "nav-fog"\ntime_offset_ms = 0.2\n'
                                   "gyro_asymmetry_ppm = [1, 2, 3]\n")
    terms = config.sim.higher_order
    assert terms is not None
    shown = terms.to_display()
    assert shown["time_offset_ms"] == pytest.approx(0.2)
    assert shown["gyro_asymmetry_ppm"] == pytest.approx([1.0, 2.0, 3.0])
    np.testing.assert_allclose(shown["acc_lever_arm_mm"], preset("nav-fog")["acc_lever_arm_mm"], rtol=1e-12)


@pytest.mark.parametrize(("text", "message"), [
    ('grade = "strategic"', "grade"),
    ("gyro_asymmetry_ppm = [1, 2]", "gyro_asymmetry_ppm"),
    ("acc_lever_arm_mm = [1, 2, 3]", "3 rows of 3"),
    ("acc_cross_ug_per_g2 = [[1, 0, 0], [0, 0, 0], [0, 0, 0]]", "diagonal"),
    ("acc_second_order_ug_per_g2 = [0, 0, 1e9]", "within"),
    ("time_offset_ms = 1000", "time_offset_ms"),
    ("size_effect = true", "size_effect"),
])
def test_bad_higher_order_keys_get_one_clear_line(text, message):
    with pytest.raises(ConfigError) as caught:
        parse_config(CONFIG + "[sim.imu.higher_order]\n" + text + "\n")
    assert message in str(caught.value) and "higher_order" in str(caught.value)


@pytest.mark.slow
def test_bench_run_on_the_simulator_carries_the_configured_terms(tmp_path):
    """The whole path (configuration, the simulated world behind CAN, the sequencer, the solve): the MEMS grade's
    accelerometer second-order term and asymmetry move the accelerometer biases and fail their residual test."""
    def k0_and_flags(extra: str, out) -> tuple[dict, list]:
        text = config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0) + extra
        with api_run(text, out) as (_run, outcome):
            assert outcome.error is None, outcome.error
            result = load_json(only_file(out, "*.result.json"))
        return ({name: result["coefficients"][name]["value"] for name in ("K0_x", "K0_y", "K0_z")},
                result["quality"]["flags"])

    clean, clean_flags = k0_and_flags("", tmp_path / "off")
    terms = ('[sim.imu.higher_order]\ngrade = "none"\nacc_second_order_ug_per_g2 = [150.0, -100.0, 200.0]\n')
    biased, flags = k0_and_flags(terms, tmp_path / "on")
    assert not any("accelerometers" in flag for flag in clean_flags)
    assert any(flag.startswith("accelerometers") for flag in flags)
    # noise-free: a second-order term Q a^2 is Q g^2 at the positions where an axis is vertical, zero where it is
    # level; the 12-position solve takes a share of it as the bias
    for axis, q_ug in zip("xyz", (150.0, -100.0, 200.0)):
        shift_ug = (biased[f"K0_{axis}"] - clean[f"K0_{axis}"]) / 1e-6
        assert 0.1 * abs(q_ug) < abs(shift_ug) < abs(q_ug) and np.sign(shift_ug) == np.sign(q_ug), (axis, shift_ug)
