"""`bench export --format yaml`: an IMU file kalibr reads (issue 33, item 1).

kalibr's rules are restated here from its documentation (the wiki's "YAML formats" and "IMU Noise
Model" pages, and what its IMU configuration reader demands; "Extending Kalibr" for the
scale-misalignment model), not taken from its code:

- the IMU file is one YAML mapping whose top level holds `rostopic` (a string), `update_rate` (Hz,
  positive) and the four continuous-time noise terms `accelerometer_noise_density` (m/s^2/sqrt(Hz)),
  `accelerometer_random_walk` (m/s^3/sqrt(Hz)), `gyroscope_noise_density` (rad/s/sqrt(Hz)) and
  `gyroscope_random_walk` (rad/s^2/sqrt(Hz)), each strictly positive; a missing one is an error;
  the reader discretises a density as density / sqrt(1 / update_rate);
- the scale-misalignment model: a gyro measures `M_g C_gyro_i w + A a + b_g`, an accelerometer
  `M_a a + b_a`, measurements in rad/s and m/s^2 (a ROS IMU message), `M` dimensionless (near the
  identity), `A` in (rad/s)/(m/s^2), `C_gyro_i` a rotation.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from bench.calibration.compensation import compensation_of
from bench.calibration.export import KalibrNoise, KalibrNoiseError, export_text, kalibr_noise, to_yaml
from bench.model.imu import default_sim_imu
from bench.model.noise_result import NoiseResult
from bench.model.result import CalibrationResult, coefficient_table
from bench.model.units import DEG, MICRO_G
from tests.helpers.run import cli

yaml = pytest.importorskip("yaml")

KALIBR_NOISE_KEYS = ("accelerometer_noise_density", "accelerometer_random_walk", "gyroscope_noise_density",
                     "gyroscope_random_walk")


class KalibrRefused(Exception):
    """What kalibr's reader would stop on."""


def _matrix(value, name: str) -> np.ndarray:
    m = np.array(value, dtype=float)
    if m.shape != (3, 3) or not np.all(np.isfinite(m)):
        raise KalibrRefused(f"{name} is not a 3x3 matrix of numbers")
    return m


def kalibr_read_imu(text: str) -> SimpleNamespace:
    """The IMU file as kalibr's reader takes it (KalibrRefused where it would stop)."""
    data = yaml.safe_load(text)
    if not isinstance(data, dict):
        raise KalibrRefused("not a mapping")
    try:
        topic, rate = data["rostopic"], data["update_rate"]
        noise = {key: data[key] for key in KALIBR_NOISE_KEYS}
    except KeyError as exc:
        raise KalibrRefused(f"field {exc} missing") from None
    if not isinstance(topic, str):
        raise KalibrRefused("rostopic has to be a string")
    if not isinstance(rate, (int, float)) or not rate > 0:
        raise KalibrRefused("invalid update_rate")
    for key, value in noise.items():
        if not isinstance(value, (int, float)) or not value > 0:
            raise KalibrRefused(f"invalid {key}")
    discrete = {key: value / math.sqrt(1.0 / rate) for key, value in noise.items() if key.endswith("density")}
    out = SimpleNamespace(topic=topic, rate=rate, noise=noise, discrete=discrete, model=data.get("model"))
    if out.model == "scale-misalignment":
        gyro, acc = data["gyroscopes"], data["accelerometers"]
        out.M_g, out.A, out.C_gyro_i = (_matrix(gyro[k], k) for k in ("M", "A", "C_gyro_i"))
        out.M_a = _matrix(acc["M"], "M")
        if not np.allclose(out.C_gyro_i @ out.C_gyro_i.T, np.eye(3), atol=1e-9):
            raise KalibrRefused("C_gyro_i is not a rotation")
        out.b_g, out.b_a = np.array(gyro["bias"], dtype=float), np.array(acc["bias"], dtype=float)
    return out


def kalibr_measures(imu: SimpleNamespace, rate_rad_s: np.ndarray, force_m_s2: np.ndarray):
    """The scale-misalignment model's gyro and accelerometer measurements (n, 3) for true inputs (n, 3)."""
    gyro = rate_rad_s @ (imu.M_g @ imu.C_gyro_i).T + force_m_s2 @ imu.A.T + imu.b_g
    return gyro, force_m_s2 @ imu.M_a.T + imu.b_a


def _term(value: float, upper_bound: bool = False) -> dict:
    return {"value": value, "sigma": value / 10, "unit": "-", **({"upper_bound": True} if upper_bound else {})}


def _noise_result(**override) -> NoiseResult:
    """ARW 0.1/0.2/0.15 deg/sqrt(h), RRW 1/2/3 deg/h/sqrt(h), VRW 50/60/40 ug/sqrt(Hz), RRW 30/20/10 ug/sqrt(h)."""
    channels = {}
    for i, axis in enumerate("xyz"):
        channels[f"gyro_{axis}"] = {"terms": {"arw": _term((0.1, 0.2, 0.15)[i]),
                                              "rrw": _term((1.0, 2.0, 3.0)[i], upper_bound=i == 2)}}
        channels[f"acc_{axis}"] = {"terms": {"vrw": _term((50.0, 60.0, 40.0)[i]),
                                             "rrw": _term((30.0, 20.0, 10.0)[i])}}
    channels.update(override)
    return NoiseResult(channels, 400.0, 4_000_000)


@pytest.fixture(scope="module")
def compensation():
    values = default_sim_imu().to_canonical()
    result = CalibrationResult(coefficient_table(values, {n: 1e-6 for n in values}),
                               run={"run_id": "r-1", "imu": {"model": "FOG-1", "serial": "S-1"}})
    return compensation_of(result)


def test_the_noise_terms_are_kalibrs_units_and_the_largest_axis():
    noise = kalibr_noise(_noise_result(), "n.noise.json")
    assert noise.update_rate_hz == 400.0
    assert noise.gyroscope_noise_density == pytest.approx(0.2 * DEG / 60.0, rel=1e-12)        # deg/sqrt(h)
    assert noise.gyroscope_random_walk == pytest.approx(3.0 * DEG / 3600.0 / 60.0, rel=1e-12)   # deg/h/sqrt(h)
    assert noise.accelerometer_noise_density == pytest.approx(60.0 * MICRO_G, rel=1e-12)
    assert noise.accelerometer_random_walk == pytest.approx(30.0 * MICRO_G / 60.0, rel=1e-12)
    assert noise.bounds == ("gyro_z rrw",)
    # a datasheet's 0.66 deg/sqrt(h) is kalibr's 1.9e-4 rad/s/sqrt(Hz)
    assert 0.66 * DEG / 60.0 == pytest.approx(1.92e-4, rel=1e-2)


@pytest.mark.parametrize("channel", [{"terms": {"arw": _term(0.1)}, "terms_not_resolved": {"rrw": "too short"}},
                                     {"terms": {"arw": _term(0.1), "rrw": _term(0.0)}}])
def test_a_missing_or_zero_term_is_refused_naming_it(channel):
    with pytest.raises(KalibrNoiseError, match=r"gyro_y has no rrw.*gyroscope_random_walk > 0"):
        kalibr_noise(_noise_result(gyro_y=channel), "n.noise.json")


def test_kalibrs_reader_takes_the_file_and_its_model_gives_the_imus_outputs(compensation):
    noise = kalibr_noise(_noise_result(), "n.noise.json")
    imu = kalibr_read_imu(to_yaml(compensation, noise, rostopic="/imu/raw"))
    assert imu.topic == "/imu/raw" and imu.rate == 400.0 and imu.model == "scale-misalignment"
    assert imu.noise == {key: getattr(noise, key) for key in KALIBR_NOISE_KEYS}
    # M is dimensionless: near the identity, not counts/s per rad/s
    for m in (imu.M_g, imu.M_a):
        assert np.allclose(np.diag(m), 1.0, atol=0.01) and np.all(np.abs(m - np.diag(np.diag(m))) < 0.01)
    # the topic (raw output / scale) is what kalibr's model predicts from the true inputs
    rng = np.random.default_rng(1)
    rates, forces = rng.normal(0.0, 1.0, (50, 3)), rng.normal(0.0, 9.8, (50, 3))
    gyro, acc = compensation.gyro, compensation.acc
    raw_gyro = rates @ np.linalg.inv(gyro.matrix).T + gyro.bias_counts
    raw_acc = forces @ np.linalg.inv(acc.matrix).T + acc.bias_counts
    doc = yaml.safe_load(to_yaml(compensation, noise))
    gyro_scale, acc_scale = (np.array(doc[k]["scale"]) for k in ("gyroscopes", "accelerometers"))
    predicted_gyro, predicted_acc = kalibr_measures(imu, rates, forces)
    assert np.allclose(raw_gyro / gyro_scale, predicted_gyro, rtol=1e-10, atol=1e-12)
    assert np.allclose(raw_acc / acc_scale, predicted_acc, rtol=1e-10, atol=1e-10)


def test_the_reader_rules_refuse_what_kalibr_refuses(compensation):
    """The restated rules can fail: the file as it was before (no noise terms, `imu0:` nesting) is refused."""
    text = to_yaml(compensation, kalibr_noise(_noise_result()))
    kalibr_read_imu(text)
    with pytest.raises(KalibrRefused, match="missing"):
        kalibr_read_imu("imu0:\n" + "".join(f"  {line}\n" for line in text.splitlines()))
    with pytest.raises(KalibrRefused, match="invalid gyroscope_random_walk"):
        kalibr_read_imu(text.replace("gyroscope_random_walk: ", "gyroscope_random_walk: -"))


def test_yaml_without_noise_terms_is_refused(compensation):
    with pytest.raises(KalibrNoiseError, match="--noise"):
        export_text(compensation, "yaml")
    assert isinstance(export_text(compensation, "yaml", KalibrNoise(200.0, 1.0, 1.0, 1.0, 1.0)), str)


def test_bench_export_writes_the_kalibr_file_with_noise_and_refuses_without(compensation, tmp_path):
    values = default_sim_imu().to_canonical()
    result_path = tmp_path / "r.result.json"
    CalibrationResult(coefficient_table(values, {n: 1e-6 for n in values}), run={"run_id": "r-1"}).save(result_path)
    noise_path = tmp_path / "imu.noise.json"
    _noise_result().save(noise_path)
    out = tmp_path / "imu.yaml"
    rc, _, stderr = cli(["export", str(result_path), "--out", str(out)])
    assert rc == 2 and "--noise" in stderr and len(stderr.strip().splitlines()) == 1 and not out.exists(), stderr
    rc, _, stderr = cli(["export", str(result_path), "--out", str(out), "--noise", str(noise_path),
                         "--rostopic", "/imu0"])
    assert rc == 0, stderr
    imu = kalibr_read_imu(out.read_text(encoding="utf-8"))
    assert imu.topic == "/imu0" and imu.noise["gyroscope_noise_density"] == pytest.approx(0.2 * DEG / 60.0)
    rc, _, stderr = cli(["export", str(result_path), "--out", str(tmp_path / "x.yaml"), "--noise",
                         str(tmp_path / "none.json")])
    assert rc == 2 and "none.json" in stderr and len(stderr.strip().splitlines()) == 1, stderr
