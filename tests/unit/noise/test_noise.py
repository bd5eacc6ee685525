"""Noise characterisation (issue 17): Allan deviation, fitted terms, the simulated IMU's noise, `bench noise`,
the static-noise plan and `[imu] noise = FILE`.

The long recoveries (8 h at 200 Hz, 1 h at 1 kHz, several seeds) are in
benchmarks/noise_recovery.py; here 1 h at 100 Hz keeps each case near a second.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from bench.config.load import ConfigError, parse_config
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.noise_result import FORMAT, VERSION, NoiseResult, NoiseResultError
from bench.noise.allan import (
    AllanError,
    PhaseAccumulator,
    allan_curve,
    allan_curves,
    cluster_sizes,
    integrate,
    second_difference_sums,
)
from bench.noise.covariance import avar_covariance, basis, cross_terms
from bench.noise.fit import FLICKER_FACTOR, fit_curve
from bench.noise.result import analyse
from bench.noise.simulate import sim_truth, simulate_static
from bench.noise.theory import GM_PEAK_ADEV, GM_PEAK_TAU, GM_TO_ALLAN_BI, gauss_markov_avar
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.inputs import bias_stabilities
from schedules import ScheduleError, parse_schedule
from tests.helpers.run import api_run, cli, config_text

#: All three slopes visible within an hour at 100 Hz: white, a Gauss-Markov hump, a random-walk bias.
VISIBLE = NoiseModel(gyro_arw_deg_rt_h=0.01, gyro_bias_instability_dph=0.02, acc_vrw_ug_rt_hz=30.0,
                     acc_bias_instability_ug=5.0, correlation_time_s=60.0, quantise=True,
                     gyro_rrw_dph_rt_h=0.6, acc_rrw_ug_rt_h=50.0)


# -- the Allan deviation itself ---------------------------------------------------------------------------------

@pytest.mark.parametrize("points_per_octave", [1, 4])
def test_oadev_agrees_with_allantools_to_1e_9_at_every_tau(points_per_octave):
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(7)
    n = 200_000
    # white + random walk + a large offset (a gyro's Earth rate and bias in its output units)
    y = 1e4 + rng.standard_normal(n) * 3.0 + np.cumsum(rng.standard_normal(n)) * 0.01
    curve = allan_curve(y, 200.0, points_per_octave=points_per_octave)
    taus, adev, _, _ = allantools.oadev(y, rate=200.0, data_type="freq", taus=curve.tau_s)
    assert len(taus) == len(curve.tau_s) and np.allclose(taus, curve.tau_s, rtol=1e-12)
    assert np.max(np.abs(adev / curve.adev - 1.0)) < 1e-9


def test_phase_accumulated_block_by_block_agrees_with_allantools_to_1e_9():
    # what a streaming log reader feeds: uneven blocks of six channels, the mean unknown in advance (the first
    # block's is taken off), the array regrown past its capacity
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(11)
    n = 150_000
    data = rng.standard_normal((n, 6)) * 3.0 + np.cumsum(rng.standard_normal((n, 6)), axis=0) * 0.02
    data += np.array([1e4, -2e4, 7.0, 9.8e6, 3.0, -1e5])      # Earth rate and biases, gravity in ug
    acc = PhaseAccumulator(200.0, 6, capacity=1000)
    edges = np.sort(rng.choice(np.arange(1, n), size=40, replace=False))
    for block in np.split(data, edges):
        acc.add(block)
    assert acc.n_samples == n
    curves = acc.curves(points_per_octave=2)
    whole = allan_curves(data, 200.0, points_per_octave=2)
    for k, curve in enumerate(curves):
        _, adev, _, _ = allantools.oadev(data[:, k], rate=200.0, data_type="freq", taus=curve.tau_s)
        assert np.max(np.abs(adev / curve.adev - 1.0)) < 1e-9, k
        assert np.max(np.abs(whole[k].adev / curve.adev - 1.0)) < 1e-9, k
        assert np.array_equal(whole[k].edf, curve.edf)


def test_a_drift_far_above_the_noise_keeps_1e_9_agreement_with_allantools():
    # the first-difference identity cancels when a drift dwarfs the noise (2e-6 off here if used throughout):
    # those sizes are summed directly
    allantools = pytest.importorskip("allantools")
    rng = np.random.default_rng(3)
    n = 300_000
    y = rng.standard_normal(n) * 1e-3 + np.linspace(0.0, 1.0, n) ** 2 * 1e6 + np.cumsum(rng.standard_normal(n)) * 0.5
    curve = allan_curve(y, 100.0)
    _, adev, _, _ = allantools.oadev(y, rate=100.0, data_type="freq", taus=curve.tau_s)
    assert np.max(np.abs(adev / curve.adev - 1.0)) < 1e-9


def test_the_threads_split_the_record_without_changing_the_sums():
    rng = np.random.default_rng(5)
    x = np.cumsum(rng.standard_normal((2, 300_001)), axis=1)
    sizes = cluster_sizes(300_000)
    direct = np.array([[np.sum((x[k, 2 * m:] - 2 * x[k, m:x.shape[1] - m] + x[k, :x.shape[1] - 2 * m]) ** 2)
                        for m in sizes] for k in range(2)])
    for threads in (1, 2, 3, 5):          # channels per thread, and parts of the record per thread
        assert np.allclose(second_difference_sums(x, sizes, threads=threads), direct, rtol=1e-12), threads
    assert np.allclose(second_difference_sums(x[1], sizes, threads=2)[0], direct[1], rtol=1e-12)


def test_a_block_of_another_width_or_not_finite_is_refused():
    acc = PhaseAccumulator(100.0, 6)
    with pytest.raises(AllanError, match="6 channel"):
        acc.add(np.zeros((10, 5)))
    with pytest.raises(AllanError, match="not finite"):
        acc.add(np.full((10, 6), np.inf))
    block = np.ones((3000, 6))
    block[1234, 2] = np.nan
    with pytest.raises(AllanError, match="not finite"):
        acc.add(block)
    assert acc.n_samples == 0
    with pytest.raises(AllanError, match="not finite"):
        allan_curves(np.where(np.arange(600)[:, None] == 7, -np.inf, np.zeros((600, 2))), 10.0)
    with pytest.raises(AllanError, match="sample rate"):
        PhaseAccumulator(0.0, 6)


def test_cluster_sizes_are_octaves_or_denser_and_keep_four_clusters():
    assert cluster_sizes(1000).tolist() == [1, 2, 4, 8, 16, 32, 64, 128]
    dense = cluster_sizes(1000, points_per_octave=4)
    assert dense[0] == 1 and dense[-1] <= 250 and np.all(np.diff(dense) > 0) and len(dense) > 20
    with pytest.raises(AllanError):
        cluster_sizes(3)
    with pytest.raises(AllanError, match="not finite"):
        allan_curve(np.array([1.0, np.nan] * 50), 10.0)


def test_integrate_is_allantools_phase():
    y = np.array([1.0, 2.0, 4.0])
    assert np.allclose(integrate(y, 2.0), [0.0, (1 - 7 / 3) / 2, (1 - 7 / 3 + 2 - 7 / 3) / 2, 0.0], atol=1e-15)


def test_white_noise_adev_and_intervals():
    rng = np.random.default_rng(1)
    sigma, rate = 2.0, 100.0
    curve = allan_curve(rng.standard_normal(400_000) * sigma, rate)
    expected = sigma / np.sqrt(curve.m)            # ADEV of white noise: sigma / sqrt(m)
    assert np.all(curve.adev_low < curve.adev) and np.all(curve.adev < curve.adev_high)
    inside = (curve.adev_low <= expected) & (expected <= curve.adev_high)
    assert inside.sum() >= 0.5 * len(curve.m)     # +-1 sigma intervals: ~68 % expected
    z = np.abs(np.log(curve.adev / expected)) * np.sqrt(2 * curve.edf)
    assert np.all(z < 4)
    fit = fit_curve(curve)
    assert fit.random_walk is not None
    n = fit.random_walk
    assert abs(n.value - sigma / math.sqrt(rate)) < 3 * n.sigma


# -- the simulated IMU's noise and the honest relation of its Gauss-Markov bias to "bias instability" ---------

def test_gauss_markov_theory_matches_the_simulated_bias():
    noise = NoiseModel(0.0, 0.05, 0.0, 0.0, 20.0, False)   # Gauss-Markov gyro bias alone, 0.05 deg/h, T 20 s
    data = simulate_static(noise, duration_s=4000.0, rate_hz=20.0, seed=3)
    curve = allan_curve(data[:, 0], 20.0)
    theory = np.sqrt(gauss_markov_avar(curve.tau_s, 0.05, 20.0))
    z = np.log(curve.adev / theory) * np.sqrt(2 * curve.edf)
    # (the simulator's bias is sampled, not averaged: the first few cluster sizes differ by ~1 % from the
    # continuous formula, which is many sigma there)
    assert np.all(np.abs(z[curve.m >= 16]) < 4)
    # its peak: 0.617 sigma at 1.89 T, which the 0.664 rule reads as 0.929 sigma
    taus = np.linspace(1.0, 100.0, 20_000)
    peak = np.sqrt(gauss_markov_avar(taus, 1.0, 20.0))
    assert abs(peak.max() - GM_PEAK_ADEV) < 1e-6 and abs(taus[peak.argmax()] / 20.0 - GM_PEAK_TAU) < 1e-3
    assert abs(GM_TO_ALLAN_BI - GM_PEAK_ADEV / FLICKER_FACTOR) < 1e-12 and abs(GM_TO_ALLAN_BI - 0.9294) < 1e-4


def test_rate_random_walk_is_simulated_and_recovered():
    noise = NoiseModel(0.0, 0.0, 0.0, 0.0, 300.0, False, gyro_rrw_dph_rt_h=1.0, acc_rrw_ug_rt_h=100.0)
    data = simulate_static(noise, duration_s=7200.0, rate_hz=10.0, seed=2)
    for k, truth in ((0, 1.0), (3, 100.0)):
        curve = allan_curve(data[:, k], 10.0)
        fit = fit_curve(curve)
        assert fit.rate_random_walk is not None, k
        k_per_sqrt_h = fit.rate_random_walk.value * 60.0
        assert abs(k_per_sqrt_h - truth) < 3 * fit.rate_random_walk.sigma * 60.0, (k, k_per_sqrt_h)


def test_new_noise_streams_leave_the_existing_ones_unchanged():
    # the random-walk streams are appended: a seed gives the same white and Gauss-Markov noise as before
    table = SimTable()
    base = NoiseModel(0.01, 0.02, 20.0, 3.0, 100.0, False)
    with_rrw = NoiseModel(0.01, 0.02, 20.0, 3.0, 100.0, False, gyro_rrw_dph_rt_h=0.0, acc_rrw_ug_rt_h=0.0)
    a = SimImu(default_sim_imu(), base, rate_hz=50.0, seed=4).generate(table, 20.0)
    b = SimImu(default_sim_imu(), with_rrw, rate_hz=50.0, seed=4).generate(table, 20.0)
    assert np.array_equal(a.gyro_counts, b.gyro_counts) and np.array_equal(a.acc_counts, b.acc_counts)


def test_the_model_covariance_of_the_allan_points_matches_monte_carlo():
    # neighbouring overlapping estimates correlate by ~0.5: the fit's uncertainties rest on this covariance
    rate, n, reps = 10.0, 1 << 12, 300
    white, rrw, gm_sigma, gm_time = 1.0, 0.05, 0.5, 30.0
    rng = np.random.default_rng(0)
    phi = math.exp(-1.0 / rate / gm_time)
    estimates = []
    for _ in range(reps):
        y = white * math.sqrt(rate) * rng.standard_normal(n) + np.cumsum(rrw / math.sqrt(rate) * rng.standard_normal(n))
        y += lfilter([gm_sigma * math.sqrt(1 - phi * phi)], [1.0, -phi], rng.standard_normal(n))
        estimates.append(allan_curve(y, rate).adev ** 2)
    estimates = np.array(estimates)
    sizes = cluster_sizes(n)
    coefficients = np.array([0.0, white ** 2, 0.0, rrw ** 2 / 3.0, gm_sigma ** 2])
    model = avar_covariance(cross_terms(sizes, n + 1, 1.0 / rate, gm_time), coefficients)
    assert np.allclose(estimates.mean(axis=0), basis(sizes / rate, gm_time) @ coefficients, rtol=0.1)
    measured = np.cov(estimates.T)
    sd_ratio = np.sqrt(np.diag(measured) / np.diag(model))
    assert np.all(np.abs(sd_ratio - 1.0) < 0.2), sd_ratio

    def corr(c):
        return np.diag(c / np.sqrt(np.outer(np.diag(c), np.diag(c))), 1)
    assert np.all(np.abs(corr(measured) - corr(model)) < 0.15) and np.all(corr(model)[2:] > 0.3)


@pytest.mark.slow
def test_terms_over_seeds_are_within_their_stated_uncertainty():
    # regression: the bias instability was the lowest noisy point / 0.664 with one point's chi-square sigma, and
    # missed by up to 4.6 sigma on these records; ARW and bias instability must respect their sigmas
    noise = NoiseModel(gyro_arw_deg_rt_h=0.01, gyro_bias_instability_dph=0.02, acc_vrw_ug_rt_hz=30.0,
                       acc_bias_instability_ug=5.0, correlation_time_s=60.0, quantise=False,
                       gyro_rrw_dph_rt_h=0.3, acc_rrw_ug_rt_h=30.0)
    rate = 20.0
    z: dict[str, list[float]] = {"random_walk": [], "bias_instability": []}
    for seed in range(8):
        data = simulate_static(noise, duration_s=3600.0, rate_hz=rate, seed=seed)
        truth = sim_truth(noise, default_sim_imu(), len(data), rate)["channels"]
        for channel in analyse(data, rate):
            for term in ("arw", "vrw", "bias_instability"):
                if term in channel.terms:
                    got = channel.terms[term]
                    key = "bias_instability" if term == "bias_instability" else "random_walk"
                    z[key].append((got["value"] - truth[channel.name][term]) / got["sigma"])
    for key, values in z.items():
        values = np.abs(values)
        assert len(values) == 48, key
        assert values.max() < 3.2 and np.mean(values <= 2.0) >= 0.85, (key, values.max(), np.mean(values <= 2.0))


def test_a_rate_random_walk_the_record_cannot_resolve_is_an_upper_bound():
    noise = NoiseModel(gyro_arw_deg_rt_h=0.01, gyro_bias_instability_dph=0.0, acc_vrw_ug_rt_hz=30.0,
                       acc_bias_instability_ug=0.0, correlation_time_s=60.0, quantise=False)   # no RRW at all
    data = simulate_static(noise, duration_s=1800.0, rate_hz=20.0, seed=1)
    for channel in analyse(data, 20.0):
        rrw = channel.terms.get("rrw")
        assert rrw is not None and rrw["upper_bound"] is True and "not resolved" in rrw["upper_bound_means"]
        assert rrw["value"] > 0.0
        white = channel.terms["arw" if channel.name.startswith("gyro") else "vrw"]
        assert "upper_bound" not in white
        doc = channel.to_json()["model"]
        assert doc["fit_tau_s"][0] < doc["fit_tau_s"][1] and len(doc["adev"]) == len(channel.curve.tau_s)


def test_white_noise_hidden_under_quantisation_is_an_upper_bound_not_a_number():
    # regression: acc_y of the default simulated IMU at 100 Hz for half an hour: its quantiser's pattern covers the
    # white noise up to ~10 s and its bias rises beyond; the fit gave 1.1 +- 70 ug/sqrt(Hz) (configured 10)
    noise = NoiseModel()
    data = simulate_static(noise, duration_s=1800.0, rate_hz=100.0, seed=1)
    acc_y = analyse(data, 100.0)[4]
    vrw = acc_y.terms["vrw"]
    assert vrw["upper_bound"] is True and "not resolved" in vrw["upper_bound_means"]
    assert vrw["value"] >= noise.acc_vrw_ug_rt_hz


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1])
def test_one_hour_recovers_the_configured_terms(seed):
    rate = 100.0
    data = simulate_static(VISIBLE, duration_s=3600.0, rate_hz=rate, seed=seed)
    channels = analyse(data, rate)
    truth = sim_truth(VISIBLE, default_sim_imu(), len(data), rate)["channels"]
    rrw_found = 0
    for channel in channels:
        terms, expected = channel.terms, truth[channel.name]
        white = "arw" if channel.name.startswith("gyro") else "vrw"
        assert white in terms and "bias_instability" in terms, channel.name
        for term in (white, "bias_instability", "rrw"):
            if term not in terms:
                continue
            got = terms[term]
            z = (got["value"] - expected[term]) / got["sigma"]
            assert abs(z) < 3, (channel.name, term, got, expected[term])
        assert abs(terms[white]["value"] / expected[white] - 1) < 0.10, channel.name
        rrw_found += "rrw" in terms
    assert rrw_found >= 3


# -- the result file ---------------------------------------------------------------------------------------------

def _small_result(tmp_path: Path) -> Path:
    rc, out, err = cli(["noise", "--sim", "--duration-h", "0.05", "--rate-hz", "100", "--seed", "2",
                        "--out", str(tmp_path)])
    assert rc == 0, err
    assert "gyro_x: arw" in out
    return tmp_path / "sim-0.05h-100hz-seed2.noise.json"


@pytest.mark.slow
def test_bench_noise_sim_writes_json_markdown_and_html(tmp_path):
    path = _small_result(tmp_path)
    doc = json.loads(path.read_text())
    assert (doc["format"], doc["version"]) == (FORMAT, VERSION)
    assert set(doc["channels"]) == {"gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z"}
    gyro = doc["channels"]["gyro_x"]
    assert gyro["unit"] == "deg/h" and gyro["terms"]["arw"]["unit"] == "deg/sqrt(h)"
    assert len(gyro["tau_s"]) == len(gyro["adev"]) == len(gyro["edf"]) == len(gyro["adev_low"])
    assert doc["summary"]["gyro_bias_stability_dph"] > 0 and doc["sim_truth"]["channels"]["acc_x"]["vrw"] == 10.0
    html = path.with_suffix("").with_suffix(".noise.html").read_text()
    assert "<svg" in html and "http://" not in html.replace("http://www.w3.org", "")
    md = path.with_suffix("").with_suffix(".noise.md").read_text()
    assert "| gyro_x | angle random walk |" in md and "error/sigma" in md
    loaded = NoiseResult.load(path)
    assert loaded.gyro_bias_stability_dph == doc["summary"]["gyro_bias_stability_dph"]


@pytest.mark.slow
def test_the_plot_draws_each_channels_fitted_curve_beside_its_term_lines(tmp_path):
    # the fitted total curve (the JSON `model`) was in the result but not in the figure
    import matplotlib.pyplot as plt

    from bench.report.noise import _lines
    from bench.report.plots import ALLAN_MODEL_LABEL, allan_axes_figure

    result = NoiseResult.load(_small_result(tmp_path))
    fig = allan_axes_figure(_lines(result))
    try:
        axes = {ax.get_title(): ax for ax in fig.axes if ax.get_visible()}
        assert set(axes) == set(result.channels)
        for name, ch in result.channels.items():
            by_label = {line.get_label(): line for line in axes[name].get_lines()}
            curve = by_label[ALLAN_MODEL_LABEL]
            fitted_on = ch["model"]["points"]
            assert len(fitted_on) >= 3
            np.testing.assert_allclose(curve.get_xdata(), np.asarray(ch["tau_s"])[fitted_on])
            np.testing.assert_allclose(curve.get_ydata(), np.asarray(ch["model"]["adev"])[fitted_on])
            assert len(axes[name].collections) >= 1        # its +-1 sigma band
        legend = [t.get_text() for t in fig.legends[0].get_texts()]     # one legend above the panels
        assert ALLAN_MODEL_LABEL in legend and any(t.startswith("-1/2") for t in legend)
    finally:
        plt.close(fig)


@pytest.mark.parametrize("argv, message", [
    (["noise"], "give a LOG or --sim"),
    (["noise", "x.mcap", "--sim"], "give a LOG or --sim"),
    (["noise", "--sim", "--points-per-octave", "0"], "--points-per-octave"),
    (["noise", "--sim", "--duration-h", "30", "--rate-hz", "1000"], "samples per channel"),
    (["noise", "--sim", "--gyro-arw", "nan"], "--gyro-arw"),
])
def test_bench_noise_usage_errors_are_one_line(argv, message):
    rc, _, err = cli(argv)
    assert rc == 2 and message in err and err.count("\n") == 1


def test_a_file_that_is_not_a_noise_result_is_refused(tmp_path):
    for text, message in (("{", "invalid JSON"), ('{"format": "x"}', "format"),
                          (json.dumps({"format": FORMAT, "version": 9}), "version"),
                          (json.dumps({"format": FORMAT, "version": 1, "channels": {"g": {"terms": {
                              "arw": {"value": -1}}}}, "rate_hz": 1, "n_samples": 1}), "value")):
        path = tmp_path / "bad.json"
        path.write_text(text)
        with pytest.raises(NoiseResultError, match=message):
            NoiseResult.load(path)


# -- static-noise plans, logs and [imu] noise -------------------------------------------------------------------

def test_static_schedules_hold_exactly_one_positive_position():
    head = 'format = "turntable-bench/schedule"\nversion = 1\nname = "s"\nkind = "static"\ndescription = "d"\n'
    one = parse_schedule(head + "[[position]]\nangles_deg = [0, 90, 0]\n")
    assert (one.kind, len(one.positions)) == ("static", 1)
    with pytest.raises(ScheduleError, match="exactly one"):
        parse_schedule(head + "[[position]]\nangles_deg = [0, 0, 0]\n[[position]]\nangles_deg = [0, 90, 0]\n")
    with pytest.raises(ScheduleError, match="multiple of 90"):
        parse_schedule(head + "[[position]]\nangles_deg = [0, 45, 0]\n")


def test_a_static_plan_takes_no_rotations():
    with pytest.raises(ConfigError, match=r"plan\.rotations: .*static noise recording"):
        parse_config(config_text(positions="static-noise", rotations="optimal-5s6r"))


def _noise_config(dwell_s: float = 120.0) -> str:
    return config_text(positions="static-noise", rotations="", dwell_s=dwell_s, rate_hz=100.0,
                       noise="true")


@pytest.mark.slow
def test_bench_run_of_the_static_noise_plan_writes_the_noise_result(tmp_path):
    (tmp_path / "bench.toml").write_text(_noise_config())
    rc, out, err = cli(["run", "--config", str(tmp_path / "bench.toml"), "--out", str(tmp_path / "runs"), "--quiet"])
    assert rc == 0, err
    runs = tmp_path / "runs"
    log = next(runs.glob("*.mcap"))
    result_path = log.with_suffix(".noise.json")
    doc = json.loads(result_path.read_text())
    assert doc["n_samples"] == 12000 and doc["source"]["dwell"] == "P01"
    assert doc["source"]["scales"].startswith("the simulated IMU's true")
    assert doc["source"]["damage"] == []
    assert log.with_suffix(".noise.html").exists() and log.with_suffix(".noise.md").exists()
    # the log holds the result, and `bench noise LOG` gives the same curves
    from bench.log.reader import read_log

    assert result_path.name in read_log(str(log)).attachments
    from mcap.reader import make_reader

    with open(log, "rb") as f:      # attached at the run clock's time, as every attachment (it was 0)
        attached = {a.name: a.log_time for a in make_reader(f).iter_attachments()}
    assert attached[result_path.name] > 0
    rc, _, err = cli(["noise", str(log), "--out", str(tmp_path / "again")])
    assert rc == 0, err
    again = json.loads((tmp_path / "again" / result_path.name).read_text())
    assert again["channels"] == doc["channels"]


@pytest.mark.slow
def test_bench_noise_needs_a_dwell_and_scales(tmp_path, monkeypatch):
    import bench.noise.from_log as from_log

    with api_run(_noise_config(dwell_s=30.0), tmp_path) as (_, outcome):
        assert outcome.error is None and outcome.result_path is not None
    log = next(tmp_path.glob("*.mcap"))
    real_read_log = from_log.read_log

    def as_hardware(path):
        recorded = real_read_log(path)
        recorded.metadata["run"]["mode"] = "hardware"
        return recorded

    monkeypatch.setattr(from_log, "read_log", as_hardware)
    rc, _, err = cli(["noise", str(log), "--out", str(tmp_path / "hw")])
    assert rc == 2 and "needs the scale factors of a calibration" in err and err.count("\n") == 1

    def without_dwells(path):
        recorded = real_read_log(path)
        recorded.events[:] = [e for e in recorded.events if e.kind != "step_finished"]
        return recorded

    monkeypatch.setattr(from_log, "read_log", without_dwells)
    rc, _, err = cli(["noise", str(log), "--out", str(tmp_path / "none")])
    assert rc == 2 and "no finished dwell" in err
    monkeypatch.setattr(from_log, "read_log", real_read_log)
    rc, _, err = cli(["noise", str(tmp_path / "missing.mcap")])
    assert rc == 2 and err.count("\n") == 1


@pytest.mark.slow
def test_imu_noise_file_feeds_the_bias_stabilities(tmp_path):
    result = _small_result(tmp_path)
    noise = NoiseResult.load(result)
    text = _noise_config().replace('serial = "T-0001"', 'serial = "T-0001"\ngyro_bias_stability_dph = 9.0\n'
                                   'acc_bias_stability_ug = 99.0').replace(
        'rate_hz = 100.0', f'rate_hz = 100.0\nnoise = "{result.name}"')
    config = parse_config(text, source=str(tmp_path / "bench.toml"), base_dir=tmp_path)
    assert config.imu.noise is not None and config.imu.noise.path == result
    assert bias_stabilities(config, sim=False) == (noise.gyro_bias_stability_dph, noise.acc_bias_stability_ug)
    assert bias_stabilities(config, sim=True) == (noise.gyro_bias_stability_dph, noise.acc_bias_stability_ug)
    without = parse_config(text.replace(f'noise = "{result.name}"', ""), base_dir=tmp_path)
    assert bias_stabilities(without, sim=False) == (9.0, 99.0)


@pytest.mark.parametrize("content, message", [
    (None, "no such noise result file"),
    ("{", "invalid JSON"),
    ('{"format": "turntable-bench/result", "version": 1}', "format is"),
    (json.dumps({"format": FORMAT, "version": 1, "channels": {}, "rate_hz": 100, "n_samples": 10}),
     "holds no gyro bias instability"),
])
def test_imu_noise_errors_are_one_line_with_file_line_and_key(tmp_path, content, message):
    if content is not None:
        (tmp_path / "n.json").write_text(content)
    text = _noise_config().replace('rate_hz = 100.0', 'rate_hz = 100.0\nnoise = "n.json"')
    line = text.splitlines().index('noise = "n.json"') + 1
    with pytest.raises(ConfigError) as caught:
        parse_config(text, source="bench.toml", base_dir=tmp_path)
    assert str(caught.value).startswith(f"bench.toml:{line}: imu.noise: ") and message in str(caught.value)
    assert "\n" not in str(caught.value)


@pytest.mark.parametrize("key, value, bound", [("gyro_rrw_dph_rt_h", 1001, "<= 1000"),
                                               ("acc_rrw_ug_rt_h", -1, ">= 0")])
def test_sim_noise_random_walk_keys_have_ranges(key, value, bound):
    text = config_text().replace("noise = false", f"[sim.noise]\n{key} = {value}")
    with pytest.raises(ConfigError, match=f"sim.noise.{key}: must be {bound}"):
        parse_config(text)
    good = parse_config(config_text().replace("noise = false", f"[sim.noise]\n{key} = 2.5"))
    assert getattr(good.sim.noise, key) == 2.5


@pytest.mark.slow
def test_a_static_run_whose_dwell_cannot_be_analysed_keeps_its_log_and_says_how(tmp_path, monkeypatch):
    import bench.finish.finish as finishing
    from bench.noise.from_log import NoiseInputError

    def refuse(path, **_):
        raise NoiseInputError(f"{path}: a hardware log needs the scale factors of a calibration")

    monkeypatch.setattr(finishing, "analyse_log", refuse)
    with api_run(_noise_config(dwell_s=20.0), tmp_path) as (_, outcome):
        assert outcome.error is None and outcome.result_path is None
        assert any("bench noise" in f and "--calibration" in f for f in outcome.failures)
    from bench.log.reader import read_log

    assert read_log(str(outcome.log_path)).scan().complete          # closed with its summary


@pytest.mark.slow
def test_bench_solve_of_a_static_noise_log_points_to_bench_noise(tmp_path):
    # regression: `bench solve` on a static-noise log exited 4 with "position method needs at least 4 positions"
    with api_run(_noise_config(dwell_s=20.0), tmp_path) as (_, outcome):
        assert outcome.error is None
    log = next(tmp_path.glob("*.mcap"))
    for extra in ([], ["--compare", "optimal,all"]):
        rc, out, err = cli(["solve", str(log), "--out", str(tmp_path / "solved"), *extra])
        assert rc == 2 and out == "" and err.count("\n") == 1
        assert "is a static noise recording" in err and f"bench noise {log}" in err
    assert not (tmp_path / "solved").exists()
