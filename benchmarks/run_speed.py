"""Benchmark: the full default simulated plan (`bench run --sim`) in wall time (target < 60 s).

Run: python benchmarks/run_speed.py [--repeats 3]
Each repeat runs `bench run --sim --quiet --out TMP` as a fresh process: optimal-24 +
optimal-5s6r, dwell 60 s, settle 5 s, turns at 10 deg/s, 1 revolution, IMU at 200 Hz,
noise on, every sample through the SCPI driver over loopback TCP, the python-can
virtual bus, the live decoder and the MCAP recorder; then the solve from the log.
Prints the median wall time, the simulated time it covered, the CAN frames recorded
and the frames per second of wall time, and checks from the log that no frame was lost.
"""

from __future__ import annotations

import argparse
import glob
import json
import statistics
import subprocess
import sys
import tempfile
import time

import results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    from bench.log.reader import read_log

    walls = []
    for _ in range(args.repeats):
        with tempfile.TemporaryDirectory() as out:
            t0 = time.perf_counter()
            command = [sys.executable, "-m", "bench.cli", "run", "--sim", "--quiet", "--out", out]
            code = subprocess.run(command).returncode
            walls.append(time.perf_counter() - t0)
            log = read_log(glob.glob(f"{out}/*.mcap")[0])
            result = json.load(open(glob.glob(f"{out}/*.result.json")[0]))
            link = result["run"]["imu_link"]
            sim_s = log.events[-1].time_s
            frames = len(log.read_can_frames().ids)
            print(f"exit {code}: {walls[-1]:.1f} s wall for {sim_s:.0f} s simulated ({sim_s / walls[-1]:.0f}x), "
                  f"{frames} CAN frames recorded = {frames / walls[-1]:,.0f} frames/s; link: {link['frames']} "
                  f"received, {link['samples']} samples, {link['counter_gaps'] + link['incomplete_samples']} lost; "
                  f"log complete: {log.scan().complete}")
    median = statistics.median(walls)
    print(f"median wall time over {args.repeats}: {median:.1f} s (target < 60 s: {'met' if median < 60 else 'MISSED'})")
    path = results.record("run_speed", medians_s={"bench run --sim, default plan, wall time": median},
                          ratios={"simulated time / wall time (last repeat)": sim_s / walls[-1]},
                          parameters={"repeats": args.repeats})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
