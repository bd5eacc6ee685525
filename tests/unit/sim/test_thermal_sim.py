"""The thermal simulated IMU: case temperature dynamics, coefficients over temperature, frames, config."""

from __future__ import annotations

import itertools

import can
import numpy as np
import pytest

from bench.config.load import SIM_CONFIG_TOML, ConfigError, parse_config
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.thermal import ImuThermal
from bench.sim.can_imu import SimCanImu
from bench.sim.imu import ImuSamples, SimImu
from bench.sim.table import SimTable
from bench.sim.thermal import CaseTemperature, profile
from drivers.imu import ImuSampleBlock
from drivers.imu.receiver import ImuReceiver

THERMAL = ImuThermal(reference_c=25.0, time_constant_s=120.0, polynomials={
    "Kg_x": (0.36,), "D0_y": (0.002, 1e-5), "Eg_Yx": (5e-6,), "Ka_z": (-0.5, 0.01, 1e-4), "K0_x": (5e-6,),
    "Ea_Zy": (-4e-6,)})
_channels = itertools.count()


def moving_table() -> SimTable:
    table = SimTable()
    table.move_to(0.0, (30.0, -20.0, 10.0), rate_dps=20.0, accel_dps2=40.0)
    table.turn(0.1, "inner", "ccw", 1, 30.0, 60.0)
    return table


def test_without_a_thermal_model_nothing_changes():
    plain = SimImu(default_sim_imu(), NoiseModel(), rate_hz=500.0, seed=3).generate(moving_table(), 3.0)
    again = SimImu(default_sim_imu(), NoiseModel(), rate_hz=500.0, seed=3, thermal=None).generate(moving_table(), 3.0)
    assert plain.temperature_c is None
    assert np.array_equal(plain.gyro_counts, again.gyro_counts) and np.array_equal(plain.acc_counts, again.acc_counts)


def test_soaked_at_a_temperature_the_imu_is_the_non_thermal_imu_with_that_temperatures_coefficients():
    for temperature_c in (-20.0, 25.0, 50.0):
        soaked = SimImu(default_sim_imu(), rate_hz=500.0, thermal=THERMAL, ambient_c=temperature_c)
        soaked.case.temperature_c = temperature_c          # (initial_c: soaked from the start)
        fixed = SimImu(THERMAL.coefficients_at(default_sim_imu(), temperature_c), rate_hz=500.0)
        a, b = soaked.generate(moving_table(), 3.0), fixed.generate(moving_table(), 3.0)
        assert np.allclose(a.temperature_c, temperature_c, rtol=0, atol=1e-9)
        for x, y in ((a.gyro_counts, b.gyro_counts), (a.acc_counts, b.acc_counts)):
            assert np.allclose(x, y, rtol=1e-12, atol=1e-9 * np.abs(y).max())
    # and the temperature matters: 50 degC differs from 25 degC by the polynomials
    hot = THERMAL.canonical_at(default_sim_imu(), 50.0)
    ref = default_sim_imu().to_canonical()
    assert hot["Kg_x"] - ref["Kg_x"] == pytest.approx(0.36 * 25)
    assert hot["Ka_z"] - ref["Ka_z"] == pytest.approx(-0.5 * 25 + 0.01 * 25 ** 2 + 1e-4 * 25 ** 3)
    assert hot["Eg_Yx"] - ref["Eg_Yx"] == pytest.approx(5e-6 * 25)


def test_direction_cosine_rows_stay_unit_vectors_and_the_reference_is_the_base_exactly():
    base = default_sim_imu()
    kg, d0, eg, ka, k0, ea = THERMAL.arrays_at(base, np.array([-40.0, 25.0, 85.0]))
    assert np.allclose(np.linalg.norm(eg, axis=2), 1.0, rtol=0, atol=1e-15)
    assert np.allclose(np.linalg.norm(ea, axis=2), 1.0, rtol=0, atol=1e-15)
    at_reference = ImuCoefficients(kg[1], d0[1], eg[1], ka[1], k0[1], ea[1]).to_canonical()
    assert at_reference == pytest.approx(base.to_canonical(), rel=1e-15, abs=1e-18)


def test_case_temperature_step_and_ramp_follow_the_first_order_solution():
    tau = 100.0
    case = CaseTemperature(tau, 50.0, initial_c=25.0)
    t = np.arange(1, 5001) * 0.1
    got = np.concatenate([case.advance(t[:1234]), case.advance(t[1234:])])       # two calls: continuous
    assert np.allclose(got, 50.0 - 25.0 * np.exp(-t / tau), rtol=0, atol=1e-10)
    # a ramp of the ambient (1 degC/min from 0 s): T = a (t - tau (1 - exp(-t/tau))) + T0 ... from 0
    ramp = CaseTemperature(tau, profile([0.0, 6000.0], [0.0, 100.0]), initial_c=0.0)
    t = np.linspace(0.5, 3000.0, 777)          # uneven steps across calls
    got = np.concatenate([ramp.advance(t[:100]), ramp.advance(t[100:])])
    a = 100.0 / 6000.0
    assert np.allclose(got, a * (t - tau * (1 - np.exp(-t / tau))), rtol=0, atol=1e-9)
    # the IMU lags its ambient by about tau * rate on a ramp
    assert got[-1] == pytest.approx(a * 3000.0 - a * tau, abs=1e-6)
    assert ramp.summary()["max_c"] == pytest.approx(got[-1])
    with pytest.raises(ValueError, match="increase"):
        ramp.advance(np.array([10.0]))


def test_the_imu_lags_a_changing_ambient_and_generating_in_pieces_is_identical():
    def make():
        return SimImu(default_sim_imu(), NoiseModel(), rate_hz=200.0, seed=5, thermal=THERMAL,
                      ambient_c=profile([0.0, 20.0], [25.0, 45.0]))
    whole = make().generate(moving_table(), 30.0)
    imu, table = make(), moving_table()
    parts = ImuSamples.concatenate([imu.generate(table, t) for t in (0.013, 7.5, 19.99, 30.0)])
    assert np.array_equal(whole.gyro_counts, parts.gyro_counts) and np.array_equal(whole.acc_counts, parts.acc_counts)
    assert np.allclose(whole.temperature_c, parts.temperature_c, rtol=0, atol=1e-12)
    assert whole.temperature_c[0] == pytest.approx(25.0, abs=0.01)
    assert 25.0 < whole.temperature_c[-1] < 45.0 - 5.0          # tau 120 s: far behind the ambient after 30 s
    assert np.all(np.diff(whole.temperature_c) > 0)


def test_frames_carry_the_case_temperature():
    channel = f"test_thermal_sim_{next(_channels)}"
    tx, rx = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    try:
        imu = SimImu(default_sim_imu(), rate_hz=100.0, thermal=ImuThermal(time_constant_s=10.0, initial_c=20.0),
                     ambient_c=40.0)
        sim = SimCanImu(moving_table(), imu, tx)
        with ImuReceiver(rx, rate_hz=100.0) as receiver:
            sim.step_to(5.0)
            blocks = [receiver.poll(timeout_s=0.0) for _ in range(20)] + [receiver.flush()]
        block = ImuSampleBlock.concatenate(blocks, 100.0)
    finally:
        tx.shutdown()
        rx.shutdown()
    t = np.arange(1, 501) / 100.0
    assert len(block) == 500
    assert np.allclose(block.temperature_c, 40.0 - 20.0 * np.exp(-t / 10.0), rtol=0, atol=0.005 + 1e-9)  # 0.01 LSB


# -- [sim.imu.thermal] ---------------------------------------------------------------------------

def _config(thermal_lines: str):
    return parse_config(SIM_CONFIG_TOML + "\n[sim.imu]\nD0_x = 0.05\n\n[sim.imu.thermal]\n" + thermal_lines,
                        source="bench.toml")


def test_the_thermal_table_is_read():
    config = _config("reference_c = 20.0\ntime_constant_s = 300\nambient_c = -10\nD0_x = [0.002, 1e-5]\n"
                     "Eg_Yx = [5e-6]\nKa_y = [0.5, 0.0, 1e-4]\n")
    thermal = config.sim.thermal
    assert thermal == ImuThermal(20.0, 300.0, {"D0_x": (0.002, 1e-5), "Eg_Yx": (5e-6,), "Ka_y": (0.5, 0.0, 1e-4)},
                                 -10.0, None)
    assert config.sim.imu.to_canonical()["D0_x"] == pytest.approx(0.05)        # [sim.imu] still read
    assert parse_config(SIM_CONFIG_TOML).sim.thermal is None


def _last_line_of(text: str, needle: str) -> int:
    return max(k for k, line in enumerate(text.splitlines(), start=1) if line.startswith(needle))


@pytest.mark.parametrize("lines, needle, key, message", [
    ("Eg_Xx = [1e-6]\n", "Eg_Xx", "sim.imu.thermal.Eg_Xx", "follows from the row"),
    ("D0_x = [1, 2, 3, 4]\n", "D0_x", "sim.imu.thermal.D0_x", "1 to 3 numbers"),
    ("D0_x = 0.002\n", "D0_x", "sim.imu.thermal.D0_x", "must be an array"),
    ("K0_x = [0.5]\n", "K0_x", "sim.imu.thermal.K0_x[0]", "within +-0.01 g/degC^1"),
    ("K0_x = [0.0, \"a\"]\n", "K0_x", "sim.imu.thermal.K0_x[1]", "the string 'a'"),
    ("time_constant_s = 0\n", "time_constant_s", "sim.imu.thermal.time_constant_s", "must be > 0 s"),
    ("reference_c = 400\n", "reference_c", "sim.imu.thermal.reference_c", "<= 200 degC"),
    ("Kg_q = [1.0]\n", "Kg_q", "sim.imu.thermal.Kg_q", "unknown key"),
])
def test_thermal_table_errors_name_file_line_and_key(lines, needle, key, message):
    with pytest.raises(ConfigError) as info:
        _config(lines)
    text = SIM_CONFIG_TOML + "\n[sim.imu]\nD0_x = 0.05\n\n[sim.imu.thermal]\n" + lines
    error = info.value
    assert (error.path, error.key) == ("bench.toml", key)
    assert error.line == _last_line_of(text, needle + " =")
    assert message in error.message, error.message
