"""Benchmark: does `bench noise` recover the simulated IMU's configured noise terms? (issue 17)

Run: python benchmarks/noise_recovery.py [--seeds 5] [--case 8h200 --case 1h1000]

Per case (8 h at 200 Hz, 1 h at 1 kHz: 5.76 M and 3.6 M samples per channel) and seed, the
simulated IMU alone (`bench.noise.simulate.simulate_static`) with all three slopes visible:
white noise (ARW 0.005 deg/sqrt(h), VRW 20 ug/sqrt(Hz)), a Gauss-Markov bias (0.01 deg/h,
5 ug, correlation time 100 s), a random-walk bias (RRW 0.05 deg/h/sqrt(h), 20 ug/sqrt(h)) and
count quantisation. Each fitted term is compared with the configured value; the bias
instability with what IEEE 952's rule reads from the model's theoretical curve (its minimum
over the same taus / 0.664, `bench.noise.theory`: a Gauss-Markov bias is not flicker noise).
Prints, per sensor and term: how often it was resolved, the mean and spread of the error in
sigma (z; honest uncertainties give mean ~0 and spread ~1), the largest |z| and |error| in %,
and the fractions within 1 and 2 sigma (68 % and 95 % expected). A rate random walk (or a
white noise) the record cannot tell from zero is reported as a 2-sigma upper bound: counted
apart, with how often the configured value is below the bound. A bias instability whose fitted curve still falls at the
longest tau is flagged as an upper bound of the floor beyond the record; its value is still the
minimum over the measured taus, which the truth is, so it is scored like the others.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from bench.model.imu import NoiseModel, default_sim_imu
from bench.noise.result import analyse
from bench.noise.simulate import sim_truth, simulate_static

NOISE = NoiseModel(gyro_arw_deg_rt_h=0.005, gyro_bias_instability_dph=0.01, acc_vrw_ug_rt_hz=20.0,
                   acc_bias_instability_ug=5.0, correlation_time_s=100.0, quantise=True,
                   gyro_rrw_dph_rt_h=0.05, acc_rrw_ug_rt_h=20.0)
CASES = {"8h200": (8.0, 200.0), "1h1000": (1.0, 1000.0)}


def run_case(hours: float, rate_hz: float, seeds: int) -> None:
    stats: dict[tuple[str, str], list[tuple[float, float]]] = {}
    bounds: dict[str, list[float]] = {}
    for seed in range(seeds):
        t0 = time.perf_counter()
        data = simulate_static(NOISE, duration_s=hours * 3600.0, rate_hz=rate_hz, seed=seed)
        t1 = time.perf_counter()
        channels = analyse(data, rate_hz)
        t2 = time.perf_counter()
        truth = sim_truth(NOISE, default_sim_imu(), len(data), rate_hz)["channels"]
        for channel in channels:
            sensor = "gyro" if channel.name.startswith("gyro") else "acc"
            for term, got in channel.terms.items():
                expected = truth[channel.name].get(term)
                if term == "quantisation" or not expected:
                    continue
                if term != "bias_instability" and got.get("upper_bound"):
                    bounds.setdefault(f"{sensor} {term}", []).append(got["value"] / expected)
                    continue
                stats.setdefault((sensor, term), []).append(
                    ((got["value"] - expected) / got["sigma"], 100.0 * (got["value"] / expected - 1.0)))
        print(f"  seed {seed}: simulated in {t1 - t0:.1f} s, analysed in {t2 - t1:.1f} s", flush=True)
    print(f"  {'sensor':6} {'term':18} {'resolved':>8} {'mean z':>7} {'sd z':>5} {'max|z|':>7} {'max|err|%':>9} "
          f"{'<=1 sigma':>9} {'<=2 sigma':>9}")
    for (sensor, term), rows in sorted(stats.items()):
        zs = np.array([z for z, _ in rows])
        errs = np.abs([e for _, e in rows])
        print(f"  {sensor:6} {term:18} {len(rows):>4}/{3 * seeds:<3} {zs.mean():+7.2f} {zs.std():5.2f} "
              f"{np.abs(zs).max():7.2f} {errs.max():9.1f} {np.mean(np.abs(zs) <= 1):9.2f} "
              f"{np.mean(np.abs(zs) <= 2):9.2f}")
    for key, ratios in sorted(bounds.items()):
        r = np.array(ratios)
        print(f"  {key} not resolved: {len(r)}/{3 * seeds} upper bounds, configured value below the bound "
              f"{int(np.sum(r >= 1))}/{len(r)}, bound / configured median {np.median(r):.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--case", action="append", choices=sorted(CASES))
    args = parser.parse_args()
    for name in args.case or list(CASES):
        hours, rate_hz = CASES[name]
        print(f"{hours:g} h at {rate_hz:g} Hz ({int(hours * 3600 * rate_hz):,} samples per channel), "
              f"{args.seeds} seeds:")
        run_case(hours, rate_hz, args.seeds)


if __name__ == "__main__":
    main()
