"""Using a calibration (issue 16, items 1 and 2): the compensation, `bench export`, `bench apply`.

The compensation's signs and units are proved against the simulator's truth: the true
coefficients' compensation inverts the simulated IMU's outputs to its true body rates and
specific forces. One noise-free simulated run on an ideal table (the short test plan) is
recorded once for the module and applied through `bench apply`; the C header is compiled
and run against it when a C compiler is present.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import math
import shutil
import subprocess
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.reader import make_reader

from bench.calibration.apply import TOPIC_COMPENSATED, compensate_block, log_samples
from bench.calibration.compensation import CompensationError, compensation_of
from bench.calibration.export import COMPENSATION_FORMAT, KalibrNoise, to_c_header, to_csv, to_json, to_toml, to_yaml
from bench.log.reader import read_log
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.run_section import RunInfo
from bench.model.units import DEG, G0
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from drivers.imu import DEFAULT_FD_DBC
from tests.helpers.run import CAN_RESOLUTION_COUNTS, RATE_HZ, api_run, cli, config_text

UNIT_IMU = ImuCoefficients(np.ones(3), np.zeros(3), np.eye(3), np.ones(3), np.zeros(3), np.eye(3))


def _truth_result(truth: ImuCoefficients, sigma: float = 1e-6, run: dict | None = None) -> CalibrationResult:
    values = truth.to_canonical()
    return CalibrationResult(coefficient_table(values, {n: sigma * max(abs(v), 1e-3) for n, v in values.items()}),
                             run=RunInfo.from_dict(run or {"run_id": "truth", "imu": {"model": "sim", "serial": "S-1"}},
                                                   complete=False))


def _moving_table() -> SimTable:
    """A table that rests, turns the outer frame at 30 deg/s and tilts: rates and forces on every axis."""
    table = SimTable()
    t = table.move_to(0.0, (30.0, 45.0, 60.0), rate_dps=40.0)
    t = table.turn(t + 0.5, "outer", "ccw", 1, 30.0)
    table.move_to(t + 0.5, (300.0, 200.0, 10.0), rate_dps=50.0)
    return table


# -- the compensation: signs and units against the simulator's truth --------------------------------

def test_the_true_compensation_inverts_the_simulated_imu_to_its_true_inputs():
    table, truth, rate = _moving_table(), default_sim_imu(), 100.0
    t_end = 40.0
    outputs = SimImu(truth, NoiseModel.off(), rate_hz=rate).generate(table, t_end)
    inputs = SimImu(UNIT_IMU, NoiseModel.off(), rate_hz=rate).generate(table, t_end)    # integrals of w_b, f_b
    compensation = compensation_of(_truth_result(truth))
    rates, forces = compensation.compensate(outputs.gyro_rate, outputs.acc_rate)
    true_rates, true_forces = inputs.gyro_rate, inputs.acc_rate
    assert np.abs(true_rates).max() > 0.5 and np.abs(true_forces).min() < 1.0     # the table moved on every axis
    assert np.abs(rates - true_rates).max() <= 1e-12 * np.abs(true_rates).max()
    assert np.abs(forces - true_forces).max() <= 1e-12 * np.abs(true_forces).max()
    # units asked for: deg/s and g
    dps, g = compensation.compensate(outputs.gyro_rate, outputs.acc_rate, rate_unit="deg/s", force_unit="g")
    assert np.allclose(dps, true_rates / DEG, rtol=0, atol=1e-12 * np.abs(true_rates).max() / DEG)
    assert np.allclose(g, true_forces / G0, rtol=0, atol=1e-12 * np.abs(true_forces).max() / G0)


def test_a_positive_bias_is_subtracted_and_the_matrix_is_the_inverse_of_scale_times_direction_cosines():
    truth = default_sim_imu()
    c = compensation_of(_truth_result(truth))
    assert np.allclose(c.gyro.matrix @ (truth.gyro_scale[:, None] * truth.gyro_axes), np.eye(3), atol=1e-12)
    assert np.allclose(c.acc.matrix @ (truth.acc_scale[:, None] * truth.acc_axes), np.eye(3), atol=1e-12)
    assert np.allclose(c.gyro.bias_counts, truth.gyro_scale * truth.gyro_bias, rtol=1e-14)
    # at rest in a zero-g, zero-rate world the output is the bias and compensates to zero
    zero_rate, zero_force = c.compensate(truth.gyro_output(np.zeros(3)), truth.acc_output(np.zeros(3)))
    assert np.abs(zero_rate).max() < 1e-18 and np.abs(zero_force).max() < 1e-15
    assert (truth.gyro_output(np.zeros(3)) > 0).tolist() == (truth.gyro_bias > 0).tolist()


def test_uncertainties_propagate_to_first_order():
    truth = default_sim_imu()
    result = _truth_result(truth, sigma=1e-5)
    c = compensation_of(result)
    # against the spread of the compensation of coefficients drawn with those sigmas
    values = truth.to_canonical()
    rng = np.random.default_rng(2)
    draws = []
    for _ in range(400):
        drawn = {n: v + rng.normal() * result.coefficients[n].sigma for n, v in values.items()}
        draws.append(compensation_of(CalibrationResult(coefficient_table(drawn))).gyro.matrix)
    spread = np.std(draws, axis=0)
    assert np.allclose(spread, c.gyro.matrix_sigma, rtol=0.2)
    # b = Kg D0, both with a relative sigma of 1e-5 here
    assert c.gyro.bias_sigma == pytest.approx(math.sqrt(2) * 1e-5 * np.abs(truth.gyro_scale * truth.gyro_bias),
                                              rel=1e-9)


def test_a_result_without_every_coefficient_gives_no_compensation():
    result = _truth_result(default_sim_imu())
    del result.coefficients["Ea_Yz"]
    with pytest.raises(CompensationError, match="lacks 1 of the 30 coefficients"):
        compensation_of(result)


# -- export formats --------------------------------------------------------------------------------

HOSTILE_SERIAL = 'S-1 */ #include "x"\n\u0000 "quoted"'


@pytest.fixture(scope="module")
def compensation():
    return compensation_of(_truth_result(default_sim_imu(), run={
        "run_id": "20261124T000000Z-abcdef", "finished_utc": "2026-11-24T00:00:00Z", "software_version": "0.1.0",
        "imu": {"model": "FOG-1", "serial": HOSTILE_SERIAL}}))


def test_json_export_is_versioned_and_reads_back_bit_for_bit(compensation):
    doc = json.loads(to_json(compensation))
    assert doc["format"] == COMPENSATION_FORMAT and doc["version"] == 1
    assert doc["imu_serial"] == HOSTILE_SERIAL and doc["run_id"] == "20261124T000000Z-abcdef"
    assert np.array_equal(np.array(doc["gyro"]["matrix"]), compensation.gyro.matrix)
    assert np.array_equal(np.array(doc["acc"]["bias"]), compensation.acc.bias_counts)
    assert doc["gyro"]["matrix_unit"] == "rad/s per counts/s" and doc["acc"]["output_unit"] == "m/s^2"
    assert doc["acc"]["bias_unit"] == "counts/s"


def test_toml_export_reads_back_with_tomllib(compensation):
    doc = tomllib.loads(to_toml(compensation))
    assert doc == json.loads(to_json(compensation))


def test_csv_export_has_every_number_once(compensation):
    rows = list(csv.DictReader(io.StringIO(to_csv(compensation), newline="")))
    meta = {r["quantity"]: r["value"] for r in rows if r["triad"] == "meta"}
    assert meta["imu_serial"] == HOSTILE_SERIAL
    for t in compensation.triads():
        m = {(int(r["row"]), int(r["col"])): float(r["value"]) for r in rows
             if r["triad"] == t.sensor and r["quantity"] == "matrix"}
        assert np.array_equal([[m[i, j] for j in range(3)] for i in range(3)], t.matrix)
        assert [float(r["value"]) for r in rows if r["triad"] == t.sensor and r["quantity"] == "bias"] \
            == t.bias_counts.tolist()


def test_yaml_export_carries_the_compensation_and_quotes_hostile_text(compensation):
    text = to_yaml(compensation, KalibrNoise(200.0, 1e-4, 1e-6, 1e-3, 1e-5))
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load(text)
    assert doc["model"] == "scale-misalignment" and doc["update_rate"] == 200.0 and doc["imu_serial"] == HOSTILE_SERIAL
    gyro, acc = compensation.gyro, compensation.acc
    assert np.allclose(np.diag(doc["gyroscopes"]["scale"]) @ doc["gyroscopes"]["M"] @ gyro.matrix, np.eye(3),
                       atol=1e-12)
    assert np.array_equal(doc["gyroscopes"]["C_gyro_i"], np.eye(3)) and not np.any(doc["gyroscopes"]["A"])
    assert np.array_equal(np.array(doc["accelerometers"]["compensation"]), acc.matrix)
    assert np.array_equal(np.array(doc["accelerometers"]["bias_counts"]), acc.bias_counts)


def test_the_c_header_keeps_hostile_text_inside_its_comment(compensation):
    text = to_c_header(compensation)
    comment, code = text.split("*/", 1)[0], text.split("*/", 1)[1]
    assert " * imu_model: FOG-1\n" in comment
    assert ' * imu_serial: S-1 *? #include "x"?? "quoted"\n' in comment     # one line, no end of comment
    assert "include \"x\"" not in code and "S-1" not in code


# -- bench apply on a recorded noise-free run ----------------------------------------------------

#: The shipped CAN FD layout's 64-bit increments at a resolution of 2^-40 count instead of 2^-16: the log then
#: carries the simulated IMU's increments to ~1e-12 count, so that what `bench apply` returns can be compared
#: with the truth sample by sample (with the classic layout's 1/256 count a sample is only good to that step).
FINE_FACTOR, FD_FACTOR = "9.094947017729282E-013", "1.52587890625E-005"


def _fine_dbc(folder: Path) -> None:
    text = DEFAULT_FD_DBC.read_text(encoding="utf-8")
    assert text.count(FD_FACTOR) == 6
    text = text.replace(FD_FACTOR, FINE_FACTOR).replace("[-140737488355328|140737488355328]", "[-8388608|8388607]")
    (folder / "fine.dbc").write_text(text, encoding="utf-8")


@contextlib.contextmanager
def _recorded(out: Path, text: str):
    """A run of `text` with its samples decoded from the log and the true inputs of each (its world open)."""
    with api_run(text, out) as (run, outcome):
        assert not outcome.failures and outcome.result_path is not None
        truth_path = out / "truth.result.json"
        CalibrationResult(outcome.result.sim_truth, run=outcome.result.run).save(truth_path)
        samples = log_samples(read_log(str(outcome.log_path)))
        n_end = int(samples.counter[-1]) + 1
        inputs = SimImu(UNIT_IMU, NoiseModel.off(), rate_hz=RATE_HZ).generate(run.world.table, n_end / RATE_HZ + 1e-9)
        yield SimpleNamespace(out=out, log=outcome.log_path, result=outcome.result_path, truth=truth_path,
                              true_rates=inputs.gyro_rate[samples.counter],
                              true_forces=inputs.acc_rate[samples.counter], samples=samples)


@pytest.fixture(scope="module")
def noise_free_run(tmp_path_factory):
    """A noise-free run on an ideal table (the short plan) logged at a resolution of 2^-40 count."""
    out = tmp_path_factory.mktemp("noise-free")
    _fine_dbc(out)
    text = config_text().replace(f"rate_hz = {RATE_HZ}\n", f'rate_hz = {RATE_HZ}\nfd = true\ndbc = "fine.dbc"\n')
    assert 'dbc = "fine.dbc"' in text
    with _recorded(out, text) as recorded:
        yield recorded


@pytest.fixture(scope="module")
def coarse_run(tmp_path_factory):
    """The same run with the default classic layout (1/256 count per sample)."""
    with _recorded(tmp_path_factory.mktemp("coarse"), config_text()) as recorded:
        yield recorded


def _read_csv(path: Path) -> tuple[list[str], np.ndarray]:
    with open(path, encoding="utf-8") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array(rows[1:], dtype=float)


def _can_bound(matrix: np.ndarray) -> np.ndarray:
    """Per-sample error bound from the CAN signals' resolution: one step per sample, times the rate."""
    return np.abs(matrix).sum(axis=1) * CAN_RESOLUTION_COUNTS * RATE_HZ


def _apply_csv(result: Path, log: Path, out: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rc, stdout, stderr = cli(["apply", str(result), str(log), "--out", str(out), "--rate-unit", "rad/s",
                              "--force-unit", "m/s^2"])
    assert rc == 0, stderr
    assert "compensated" in stdout
    header, data = _read_csv(out)
    assert header[3:] == ["rate_x_rps", "rate_y_rps", "rate_z_rps", "force_x_mps2", "force_y_mps2", "force_z_mps2"]
    return data, data[:, 3:6], data[:, 6:9]


def _relative(got: np.ndarray, true: np.ndarray) -> float:
    """The largest per-sample error relative to that sample's true vector."""
    return float((np.linalg.norm(got - true, axis=1) / np.linalg.norm(true, axis=1)).max())


@pytest.mark.slow
@pytest.mark.parametrize("calibration", ["solved", "truth"])
def test_bench_apply_returns_the_true_body_rates_and_specific_force(noise_free_run, tmp_path, calibration):
    """Sample by sample to 1e-9 relative, with the run's own solved calibration or the true coefficients
    (measured: solved 4.6e-10 and 3.7e-15, true 3.0e-12 and 2.8e-15)."""
    run = noise_free_run
    data, rates, forces = _apply_csv(run.result if calibration == "solved" else run.truth, run.log,
                                     tmp_path / "applied.csv")
    assert np.array_equal(data[:, 0], run.samples.counter) and len(data) == len(run.samples) > 10000
    assert np.abs(run.true_rates).max() > 0.5                     # turns at 30 deg/s, and at rest
    assert _relative(rates, run.true_rates) <= 1e-9
    assert _relative(forces, run.true_forces) <= 1e-9


@pytest.mark.slow
@pytest.mark.parametrize("calibration", ["solved", "truth"])
def test_with_the_classic_layout_a_sample_is_true_to_one_resolution_step(coarse_run, tmp_path, calibration):
    run = coarse_run
    result = run.result if calibration == "solved" else run.truth
    _, rates, forces = _apply_csv(result, run.log, tmp_path / "applied.csv")
    c = compensation_of(CalibrationResult.load(result))
    # each sample: the truth to within one CAN resolution step (the log's own quantisation), plus the solved
    # calibration's own error on this plan (3 s dwells at 1/256 count)
    rel = 1e-9 if calibration == "truth" else 5e-8
    assert np.all(np.abs(rates - run.true_rates) <= _can_bound(c.gyro.matrix) + rel * np.abs(run.true_rates).max())
    assert np.all(np.abs(forces - run.true_forces)
                  <= _can_bound(c.acc.matrix) + rel * np.abs(run.true_forces).max())
    # integrated (what a navigation computer does with them): the quantisation carries over
    for got, true, tolerance in ((rates, run.true_rates, 2e-9 if calibration == "truth" else 5e-9),
                                 (forces, run.true_forces, 5e-9 if calibration == "truth" else 5e-8)):
        integral, true_integral = np.cumsum(got, axis=0), np.cumsum(true, axis=0)
        assert np.abs(integral - true_integral).max() <= tolerance * np.abs(true_integral).max()


@pytest.mark.slow
def test_bench_apply_writes_an_mcap_with_the_raw_and_the_compensated_topics(noise_free_run, tmp_path):
    run = noise_free_run
    out = tmp_path / "applied.mcap"
    rc, _, stderr = cli(["apply", str(run.truth), str(run.log), "--out", str(out), "--quiet"])
    assert rc == 0, stderr
    with open(out, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        topics: dict[str, list] = {}
        for _schema, channel, message in reader.iter_messages():
            topics.setdefault(channel.topic, []).append(json.loads(message.data))
        metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
    assert set(topics) == {"/imu/samples", TOPIC_COMPENSATED}
    compensated = topics[TOPIC_COMPENSATED]
    assert len(compensated) == len(topics["/imu/samples"]) == len(run.samples)
    assert compensated[0]["rate_unit"] == "deg/s" and compensated[0]["force_unit"] == "g"   # the defaults
    rates = np.array([m["angular_rate"] for m in compensated]) * DEG
    forces = np.array([m["specific_force"] for m in compensated]) * G0
    assert _relative(rates, run.true_rates) <= 1e-9 and _relative(forces, run.true_forces) <= 1e-9
    assert metadata["compensation"]["source_log"] == run.log.name
    assert [m["counter"] for m in topics["/imu/samples"]] == run.samples.counter.tolist()


@pytest.mark.slow
def test_apply_and_the_library_are_one_code_path(noise_free_run):
    c = compensation_of(CalibrationResult.load(noise_free_run.truth))
    applied = compensate_block(c, noise_free_run.samples, rate_unit="deg/s", force_unit="g")
    rates, forces = c.compensate(noise_free_run.samples.gyro_rate, noise_free_run.samples.acc_rate,
                                 rate_unit="deg/s", force_unit="g")
    assert np.array_equal(applied.angular_rate, rates) and np.array_equal(applied.specific_force, forces)


C_PROGRAM = r"""
#include <stdio.h>
#include <stdlib.h>
#include "compensation.h"

int main(int argc, char **argv)
{
    FILE *in = fopen(argv[1], "r");
    double g[3], a[3], w[3], f[3];
    if (!in || argc < 2) return 2;
    while (fscanf(in, "%lf %lf %lf %lf %lf %lf", &g[0], &g[1], &g[2], &a[0], &a[1], &a[2]) == 6) {
        tb_imu_gyro_compensate(g, w);
        tb_imu_acc_compensate(a, f);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g\n", w[0], w[1], w[2], f[0], f[1], f[2]);
    }
    fclose(in);
    return tb_imu_sigmas(0)[0] >= 0.0 ? 0 : 3;
}
"""


@pytest.mark.slow
def test_the_c_header_compiles_and_compensates_a_log_as_bench_apply_does(noise_free_run, tmp_path):
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        pytest.skip("no C compiler")
    run = noise_free_run
    rc, _, stderr = cli(["export", str(run.result), "--format", "c", "--out", str(tmp_path / "compensation.h")])
    assert rc == 0, stderr
    (tmp_path / "main.c").write_text(C_PROGRAM, encoding="ascii")
    done = subprocess.run([compiler, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(tmp_path / "comp"),
                           str(tmp_path / "main.c"), "-lm"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    raw = np.hstack([run.samples.gyro_rate, run.samples.acc_rate])
    (tmp_path / "raw.txt").write_text("".join(" ".join(map(repr, row)) + "\n" for row in raw.tolist()))
    done = subprocess.run([str(tmp_path / "comp"), str(tmp_path / "raw.txt")], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    from_c = np.array([line.split() for line in done.stdout.splitlines()], dtype=float)
    rc, _, stderr = cli(["apply", str(run.result), str(run.log), "--out", str(tmp_path / "applied.csv"),
                         "--rate-unit", "rad/s", "--force-unit", "m/s^2", "--quiet"])
    assert rc == 0, stderr
    _, data = _read_csv(tmp_path / "applied.csv")
    from_python = data[:, 3:9]
    assert from_c.shape == from_python.shape == (len(run.samples), 6)
    for cols in (slice(0, 3), slice(3, 6)):       # relative to each vector's magnitude
        scale = np.linalg.norm(from_python[:, cols], axis=1, keepdims=True)
        assert np.all(np.abs(from_c[:, cols] - from_python[:, cols]) <= 1e-12 * scale)


# -- the commands' errors ----------------------------------------------------------------------------

@pytest.mark.slow
def test_export_writes_every_format_and_infers_it_from_the_suffix(noise_free_run, tmp_path):
    for name in ("c.h", "c.json", "c.csv", "c.toml"):     # c.yaml needs --noise: test_kalibr_export.py
        rc, _, stderr = cli(["export", str(noise_free_run.result), "--out", str(tmp_path / name)])
        assert rc == 0, stderr
    assert json.loads((tmp_path / "c.json").read_text())["format"] == COMPENSATION_FORMAT
    assert tomllib.loads((tmp_path / "c.toml").read_text())["imu_serial"] == "T-0001"
    assert "static const double TB_IMU_GYRO_MATRIX[3][3]" in (tmp_path / "c.h").read_text()


@pytest.mark.parametrize("content, message", [
    (b"not json", "invalid JSON"),
    (b"\xff\xfe", "not UTF-8"),
    (b"[" * 100000 + b"]" * 100000, "nested too deeply"),
    (json.dumps({"format": "turntable-bench/result", "version": 1, "coefficients": {}}).encode(),
     "lacks 30 of the 30"),
    (json.dumps({"format": "other"}).encode(), "not a turntable-bench/result"),
])
def test_a_bad_result_file_is_one_line_and_exit_2(tmp_path, content, message):
    bad = tmp_path / "bad.result.json"
    bad.write_bytes(content)
    for argv in (["export", str(bad), "--out", str(tmp_path / "x.json")],
                 ["apply", str(bad), str(tmp_path / "no.mcap"), "--out", str(tmp_path / "x.csv")]):
        rc, _, stderr = cli(argv)
        assert rc == 2 and message in stderr and len(stderr.strip().splitlines()) == 1, stderr


@pytest.mark.slow
def test_apply_refuses_a_file_that_is_no_log_and_never_overwrites_the_log(noise_free_run, tmp_path):
    not_a_log = tmp_path / "x.mcap"
    not_a_log.write_bytes(b"hello" * 100)
    rc, _, stderr = cli(["apply", str(noise_free_run.truth), str(not_a_log), "--out", str(tmp_path / "o.csv")])
    assert rc == 2 and len(stderr.strip().splitlines()) == 1, stderr
    rc, _, stderr = cli(["apply", str(noise_free_run.truth), str(noise_free_run.log), "--out",
                         str(noise_free_run.log)])
    assert rc == 2 and "a file this command reads" in stderr
    rc, _, stderr = cli(["apply", str(noise_free_run.truth), str(noise_free_run.log), "--out", str(tmp_path / "o.txt")])
    assert rc == 2 and "--format" in stderr
