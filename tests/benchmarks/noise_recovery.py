"""Benchmark: does `bench noise` recover the simulated IMU's configured noise terms? (issue 17)

Run: python tests/benchmarks/noise_recovery.py [--seeds 5] [--case 8h200 --case 1h1000]

Per case (8 h at 200 Hz, 1 h at 1 kHz: 5.76 M and 3.6 M samples per channel) and seed, the
simulated IMU alone (`bench.noise.simulate.simulate_static`) with all three slopes visible:
white noise (ARW 0.005 deg/sqrt(h), VRW 20 ug/sqrt(Hz)), a Gauss-Markov bias (0.01 deg/h,
5 ug, correlation time 100 s), a random-walk bias (RRW 0.05 deg/h/sqrt(h), 20 ug/sqrt(h)) and
count quantisation. Each fitted term is compared with the configured value; the bias
instability with what IEEE 952's rule reads from the model's theoretical curve (its minimum
over the same taus / 0.664, `bench.noise.theory`: a Gauss-Markov bias is not flicker noise).
Prints, per sensor and term: how often it was found, the largest |error| in sigma and in %,
and how many of the errors were within 1 and 2 sigma (a bias instability flagged as an upper
bound, the curve still falling at its longest tau, is counted apart).
"""

from __future__ import annotations

import argparse
import time

from bench.model.imu import NoiseModel, default_sim_imu
from bench.noise.result import analyse
from bench.noise.simulate import sim_truth, simulate_static

NOISE = NoiseModel(gyro_arw_deg_rt_h=0.005, gyro_bias_instability_dph=0.01, acc_vrw_ug_rt_hz=20.0,
                   acc_bias_instability_ug=5.0, correlation_time_s=100.0, quantise=True,
                   gyro_rrw_dph_rt_h=0.05, acc_rrw_ug_rt_h=20.0)
CASES = {"8h200": (8.0, 200.0), "1h1000": (1.0, 1000.0)}


def run_case(hours: float, rate_hz: float, seeds: int) -> None:
    stats: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for seed in range(seeds):
        t0 = time.perf_counter()
        data = simulate_static(NOISE, duration_s=hours * 3600.0, rate_hz=rate_hz, seed=seed)
        t1 = time.perf_counter()
        channels = analyse(data, rate_hz)
        t2 = time.perf_counter()
        truth = sim_truth(NOISE, default_sim_imu(), len(data), rate_hz)["channels"]
        for channel in channels:
            for term, got in channel.terms.items():
                expected = truth[channel.name].get(term)
                if term == "quantisation" or not expected:
                    continue
                z = (got["value"] - expected) / got["sigma"]
                # a bias instability the record does not reach the floor of is flagged as an upper bound:
                # counted apart
                name = term + (" (upper bound)" if got.get("upper_bound") else "")
                stats.setdefault((channel.name[:3].replace("gyr", "gyro"), name), []).append(
                    (z, 100.0 * (got["value"] / expected - 1.0)))
        print(f"  seed {seed}: simulated in {t1 - t0:.1f} s, analysed in {t2 - t1:.1f} s", flush=True)
    print(f"  {'sensor':6} {'term':30} {'found':>7} {'max|z|':>7} {'max|err|%':>9} {'<=1 sigma':>9} {'<=2 sigma':>9}")
    for (sensor, term), rows in sorted(stats.items()):
        zs, errs = [abs(z) for z, _ in rows], [abs(e) for _, e in rows]
        print(f"  {sensor:6} {term:30} {len(rows):>3}/{3 * seeds:<3} {max(zs):7.2f} {max(errs):9.1f} "
              f"{sum(z <= 1 for z in zs):>5}/{len(zs):<3} {sum(z <= 2 for z in zs):>5}/{len(zs):<3}")


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
