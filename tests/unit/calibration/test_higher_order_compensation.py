"""The extended model's compensation (issue 30 item 6): a result with the higher-order families compensates the
simulated IMU with that truth (`[sim.imu.higher_order]`) to its true rates and specific forces, at rest and in a
turn; a result of the 30 coefficients compensates as before; the exports carry the families in every format."""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
import shutil
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pytest

from bench.calibration.compensation import Compensation, CompensationError, TriadCompensation, compensation_of
from bench.calibration.export import KalibrNoise, to_c_header, to_csv, to_json, to_toml, to_yaml
from bench.model.earth import Site
from bench.model.extended import FAMILIES, MEAN_TERMS, family_of_name
from bench.model.higher_order import HigherOrderTerms, preset
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.run_section import RunInfo
from bench.model.units import DEG, DEG_PER_HOUR, MICRO_G
from bench.sim.imu import SimImu
from bench.sim.table import SimTable, TableLimits
from studies.extended_coverage import truth_values
from tests.helpers.run import cli

RATE_HZ = 1000.0
UNIT_IMU = ImuCoefficients(np.ones(3), np.zeros(3), np.eye(3), np.ones(3), np.zeros(3), np.eye(3))
LIMITS = TableLimits((400.0, 400.0, 400.0), (2000.0, 2000.0, 2000.0))
TURN_DPS = 150.0
#: white noise only (a good tactical unit's levels): a window's mean then has a known standard error
WHITE = NoiseModel(gyro_arw_deg_rt_h=0.05, gyro_bias_instability_dph=0.0, acc_vrw_ug_rt_hz=20.0,
                   acc_bias_instability_ug=0.0, quantise=False)


def _terms(axes: np.ndarray) -> HigherOrderTerms:
    """The tactical-MEMS truth without what the model does not hold: no time offset, and each accelerometer's
    lever arm along its own axis (`axes`: the accelerometers' direction cosines; a component across it moves a
    body-axis turn's output only through the misalignment, and the solve does not estimate it)."""
    display = preset("tactical-mems")
    display["time_offset_ms"] = 0.0
    own = np.diag(np.asarray(display["acc_lever_arm_mm"], dtype=float))
    display["acc_lever_arm_mm"] = (own[:, None] * axes / np.linalg.norm(axes, axis=1, keepdims=True)).tolist()
    return HigherOrderTerms.from_display(display)


def _result(truth: ImuCoefficients, terms: HigherOrderTerms | None) -> CalibrationResult:
    values = {**truth.to_canonical(), **(truth_values(terms) if terms is not None else {})}
    return CalibrationResult(coefficient_table(values, {n: 1e-6 * max(abs(v), 1e-3) for n, v in values.items()}),
                             run=RunInfo.from_dict({"run_id": "truth", "imu": {"model": "sim", "serial": "S-1"}},
                                                   complete=False))


def _table() -> tuple[SimTable, tuple[float, float], tuple[float, float], float]:
    """Rest at a tilt, then the inner frame (body Z, 45 deg off the vertical) at a constant rate: gravity turns
    through both signs of body X and Y. (rest window, turn window, end)."""
    table = SimTable(Site(30.27), limits=LIMITS)
    rest = table.move_to(0.0, (30.0, 45.0, 60.0), rate_dps=100.0)
    steady = table.set_rate(rest + 6.0, "inner", -TURN_DPS, accel_dps2=500.0)
    end = steady + 4.8         # two revolutions at 150 deg/s
    return table, (rest + 0.2, rest + 6.0), (steady + 0.1, end), end


@pytest.fixture(scope="module")
def world():
    table, rest, turn, end = _table()
    truth = default_sim_imu()
    terms = _terms(truth.acc_axes)

    def run(noise: NoiseModel):
        return SimImu(truth, noise, rate_hz=RATE_HZ, seed=5, higher_order=terms).generate(table, end)
    true = SimImu(UNIT_IMU, NoiseModel.off(), rate_hz=RATE_HZ).generate(table, end)    # sample means of w_b, f_b
    return {"truth": truth, "terms": terms, "rest": rest, "turn": turn, "true": true, "clean": run(NoiseModel.off()),
            "noisy": run(WHITE)}


def _window(samples, window: tuple[float, float]) -> np.ndarray:
    return (samples.time_s > window[0]) & (samples.time_s <= window[1])


def test_the_truths_coefficients_give_the_true_inputs_at_rest_and_in_a_turn(world):
    true, clean = world["true"], world["clean"]
    extended = compensation_of(_result(world["truth"], world["terms"]))
    linear = compensation_of(_result(world["truth"], None))
    assert extended.higher_order is not None and list(extended.higher_order.terms) == list(MEAN_TERMS)
    assert linear.higher_order is None
    rate, force = extended.compensate(clean.gyro_rate, clean.acc_rate)
    rate0, force0 = linear.compensate(clean.gyro_rate, clean.acc_rate)
    for name in ("rest", "turn"):
        k = _window(true, world[name])
        assert k.sum() > 1000
        w_err = np.abs(rate[k] - true.gyro_rate[k]).max() / DEG_PER_HOUR
        f_err = np.abs(force[k] - true.acc_rate[k]).max() / MICRO_G
        w_err0 = np.abs(rate0[k] - true.gyro_rate[k]).max() / DEG_PER_HOUR
        f_err0 = np.abs(force0[k] - true.acc_rate[k]).max() / MICRO_G
        # the 30 coefficients leave the higher-order terms (tens of deg/h, hundreds of ug); the extended
        # compensation leaves its remainder
        assert w_err0 > 5.0 and f_err0 > 100.0, (name, w_err0, f_err0)
        assert w_err < 1e-3 and f_err < 0.5, (name, w_err, f_err)         # measured: 2e-6 deg/h, 0.11 ug
    # the turn shows every family: the lever arms' centripetal force and the rate's square are large there
    k = _window(true, world["turn"])
    assert np.abs(true.gyro_rate[k, 2]).min() / DEG == pytest.approx(TURN_DPS, rel=1e-3)


def test_with_noise_the_error_left_is_the_noise(world):
    true, noisy = world["true"], world["noisy"]
    extended = compensation_of(_result(world["truth"], world["terms"]))
    linear = compensation_of(_result(world["truth"], None))
    for name in ("rest", "turn"):
        k = _window(true, world[name])
        for c, extended_model in ((extended, True), (linear, False)):
            rate, force = c.compensate(noisy.gyro_rate[k], noisy.acc_rate[k])
            t = np.concatenate([np.abs(e.mean(axis=0)) / (e.std(axis=0) / np.sqrt(k.sum()))
                                for e in (rate - true.gyro_rate[k], force - true.acc_rate[k])])
            # white noise: each axis' mean error over the window in standard errors; the 30 coefficients leave far
            # more (at rest the accelerometers' second order and asymmetry; in the turn the lever arms too)
            assert t.max() < 4.0 if extended_model else t.max() > 10.0, (name, extended_model, t)


def test_a_family_with_a_coefficient_missing_gives_no_compensation(world):
    result = _result(world["truth"], world["terms"])
    del result.coefficients["Gg_Yz"]
    with pytest.raises(CompensationError, match="part of the gyro g-sensitivity"):
        compensation_of(result)


# -- export ---------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def extended(world):
    return compensation_of(_result(world["truth"], world["terms"]))


def _fixed_compensation() -> Compensation:
    """A 30-coefficient compensation of fixed numbers (no matrix inverse: its texts are the same on any machine)."""
    def triad(sensor: str, unit: str, offset: float) -> TriadCompensation:
        matrix = np.array([[1.5e-6, 2.5e-9, -3.25e-9], [1.0e-9, 1.25e-6, 4.5e-9], [-2.0e-9, 3.0e-9, 1.75e-6]]) + offset
        return TriadCompensation(sensor, unit, matrix, np.array([12.5, -7.25, 3.0]) + offset,
                                 np.full((3, 3), 1e-12), np.array([0.5, math.nan, 0.25]),
                                 np.array([6.0e5, 7.5e5, 5.5e5]), np.array([2e-5, -1e-5, 5e-6]))
    return Compensation(triad("gyro", "rad/s", 0.0), triad("acc", "m/s^2", 1e-7), imu_model="FOG-1",
                        imu_serial='S-1 */ "q"', run_id="20261124T000000Z-abcdef",
                        calibrated_utc="2026-11-24T00:00:00Z", software_version="0.1.0")


#: the texts' digests (with `exported_by` blanked) as main b3e0960 wrote them, before the extended model's export
DIGESTS_30 = {"json": "ef35f3f3308e9cf7", "csv": "dcd462679bc1f7a5", "c": "ad27c97bce26b73c",
              "toml": "ab707500a7dbcab6", "yaml": "da6b389f90fe88b5"}


def test_a_30_coefficient_result_exports_exactly_what_it_did():
    from bench import __version__
    c = _fixed_compensation()
    texts = {"json": to_json(c), "csv": to_csv(c), "c": to_c_header(c), "toml": to_toml(c),
             "yaml": to_yaml(c, KalibrNoise(200.0, 1e-4, 1e-6, 1e-3, 1e-5))}
    digests = {k: hashlib.sha256(v.replace(f"turntable-bench {__version__}", "EXPORTED_BY").encode()).hexdigest()[:16]
               for k, v in texts.items()}
    assert digests == DIGESTS_30


def test_json_and_toml_carry_every_family_in_si(extended):
    doc = json.loads(to_json(extended))
    assert doc["version"] == 2
    higher = doc["higher_order"]
    assert list(higher["terms"]) == list(MEAN_TERMS) and set(higher["equations"]) == {"gyro", "acc"}
    for name, term in extended.higher_order.terms.items():
        assert np.array_equal(higher["terms"][name]["value"], term.value)
        assert np.array_equal(higher["terms"][name]["sigma"], term.sigma)
        assert higher["terms"][name]["unit"] == term.unit
    assert higher["terms"]["gyro_g_sensitivity"]["unit"] == "rad/s per m/s^2"
    assert np.array_equal(higher["gyro_scale"], extended.gyro.scale)
    assert np.array_equal(higher["acc_scale"], extended.acc.scale)
    assert tomllib.loads(to_toml(extended)) == doc
    jsonschema = pytest.importorskip("jsonschema")
    schema = json.loads((Path(__file__).resolve().parents[3] / "docs" / "reference" / "schemas"
                         / "compensation.schema.json").read_text(encoding="utf-8"))
    jsonschema.validate(doc, schema)
    jsonschema.validate(json.loads(to_json(_fixed_compensation())), schema)


def test_csv_has_each_coefficient_once(extended):
    rows = list(csv.DictReader(io.StringIO(to_csv(extended), newline="")))
    assert next(r for r in rows if r["quantity"] == "format")["value"].endswith(" 2")
    for name, term in extended.higher_order.terms.items():
        found = [r for r in rows if r["quantity"] == name]
        assert len(found) == len(FAMILIES[name].names)          # the cross terms' diagonal is no coefficient
        for r in found:
            index = (int(r["row"]), int(r["col"])) if r["col"] else int(r["row"])
            assert float(r["value"]) == term.value[index] and r["unit"] == term.unit


def test_kalibr_yaml_holds_the_g_sensitivity_and_names_what_it_leaves_out(extended):
    text = to_yaml(extended, KalibrNoise(200.0, 1e-4, 1e-6, 1e-3, 1e-5))
    yaml = pytest.importorskip("yaml")
    doc = yaml.safe_load(text)
    assert np.array_equal(doc["gyroscopes"]["A"], extended.higher_order.terms["gyro_g_sensitivity"].value)
    left_out = [line for line in text.splitlines() if line.startswith("# kalibr's model has no")]
    assert len(left_out) == 1 and "acc_lever_arm" in left_out[0] and "gyro_g_sensitivity" not in left_out[0]


C_MAIN = r"""
#include <stdio.h>
#include "compensation.h"
int main(void)
{
    double g[3], a[3], w[3], f[3];
    while (scanf("%lf %lf %lf %lf %lf %lf", &g[0], &g[1], &g[2], &a[0], &a[1], &a[2]) == 6) {
        tb_imu_compensate(g, a, w, f);
        printf("%.17g %.17g %.17g %.17g %.17g %.17g\n", w[0], w[1], w[2], f[0], f[1], f[2]);
    }
    return tb_imu_sigmas(0)[0] >= 0.0 && tb_imu_higher_order_sigmas(0)[0] >= 0.0 ? 0 : 3;
}
"""


@pytest.mark.parametrize("families", [MEAN_TERMS, ("acc_lever_arm",), ("gyro_asymmetry", "acc_cross"),
                                      ("gyro_g_sensitivity",), ("acc_second_order",)])
def test_the_c_header_compensates_as_bench_apply_does(world, tmp_path, families):
    compiler = shutil.which("cc") or shutil.which("gcc") or shutil.which("clang")
    if compiler is None:
        pytest.skip("no C compiler")
    result = _result(world["truth"], world["terms"])
    for name in [n for n in result.coefficients if (f := family_of_name(n)) is not None and f.term not in families]:
        del result.coefficients[name]
    c = compensation_of(result)
    assert c.higher_order is not None and tuple(c.higher_order.terms) == families
    (tmp_path / "compensation.h").write_text(to_c_header(c), encoding="ascii")
    (tmp_path / "main.c").write_text(C_MAIN, encoding="ascii")
    done = subprocess.run([compiler, "-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-o", str(tmp_path / "comp"),
                           str(tmp_path / "main.c"), "-lm"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    clean = world["clean"]
    pick = slice(0, None, 7)               # rest, ramp and turn, a seventh of the samples
    raw = np.hstack([clean.gyro_rate[pick], clean.acc_rate[pick]])
    lines = "".join(" ".join(map(repr, row)) + "\n" for row in raw.tolist())
    done = subprocess.run([str(tmp_path / "comp")], input=lines, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    from_c = np.array([line.split() for line in done.stdout.splitlines()], dtype=float)
    rate, force = c.compensate(clean.gyro_rate[pick], clean.acc_rate[pick])
    assert from_c.shape == (len(raw), 6)
    for mine, theirs in ((rate, from_c[:, :3]), (force, from_c[:, 3:])):
        assert np.all(np.abs(theirs - mine) <= 1e-12 * np.linalg.norm(mine, axis=1, keepdims=True))


def test_bench_export_writes_the_families_of_a_result_file(world, tmp_path):
    path = tmp_path / "extended.result.json"
    _result(world["truth"], world["terms"]).save(path)
    for name in ("c.json", "c.toml", "c.csv", "c.h"):
        rc, _, stderr = cli(["export", str(path), "--out", str(tmp_path / name)])
        assert rc == 0, stderr
    doc = json.loads((tmp_path / "c.json").read_text())
    assert doc["version"] == 2 and list(doc["higher_order"]["terms"]) == list(MEAN_TERMS)
    assert tomllib.loads((tmp_path / "c.toml").read_text()) == doc
    assert "tb_imu_compensate" in (tmp_path / "c.h").read_text()


def test_bench_apply_applies_the_families(short_run, world, tmp_path):
    """`bench apply` of a result with the families gives `Compensation.compensate` of the log's samples, and not
    what the 30 coefficients alone give."""
    from bench.calibration.apply import log_samples
    from bench.log.reader import read_log
    result = CalibrationResult.load(short_run.result)
    for name, value in truth_values(world["terms"]).items():
        result.coefficients[name] = coefficient_table({name: value}, {name: 0.1 * abs(value)})[name]
    path = tmp_path / "extended.result.json"
    result.save(path)
    out = tmp_path / "applied.csv"
    rc, _, stderr = cli(["apply", str(path), str(short_run.log), "--out", str(out), "--rate-unit", "rad/s",
                         "--force-unit", "m/s^2", "--quiet"])
    assert rc == 0, stderr
    applied = np.loadtxt(out, delimiter=",", skiprows=1)[:, 3:9]
    samples = log_samples(read_log(str(short_run.log)))
    rate, force = compensation_of(result).compensate(samples.gyro_rate, samples.acc_rate)
    assert np.array_equal(applied, np.hstack([rate, force]))
    rate0, force0 = compensation_of(CalibrationResult.load(short_run.result)).compensate(samples.gyro_rate,
                                                                                       samples.acc_rate)
    assert np.abs(force - force0).max() > 1e-4 and np.abs(rate - rate0).max() > 1e-5    # m/s^2, rad/s
