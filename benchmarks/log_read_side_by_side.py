"""Benchmark: reading IMU samples out of a log with two checkouts of the code, side by side.

Run: python benchmarks/log_read_side_by_side.py --before ROOT LOG --after ROOT LOG [--repeats 5]

Each ROOT is a checkout (e.g. a `git worktree` of an older commit), each LOG a log written by that
checkout's recorder (`benchmarks/log_read_speed.py --build-only --cache DIR` with that checkout
on PYTHONPATH writes one). Every repeat runs both in fresh processes, alternating, and times
`read_log` + `RunLog.imu_samples(default layout, 1 kHz)`; prints the medians, the spreads and the ratio.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys

import results

_TIMED = r'''
import sys, time
sys.path.insert(0, sys.argv[1])
from bench.log.reader import read_log
from drivers.imu import default_layout
t = time.perf_counter()
log = read_log(sys.argv[2])
block, _ = log.imu_samples(default_layout(), 1000.0)
print(time.perf_counter() - t, len(block))
'''


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", nargs=2, metavar=("ROOT", "LOG"), required=True)
    parser.add_argument("--after", nargs=2, metavar=("ROOT", "LOG"), required=True)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    runs = {"before": args.before, "after": args.after}
    times: dict[str, list[float]] = {k: [] for k in runs}
    samples = {}
    for _ in range(args.repeats):
        for name, (root, log) in runs.items():
            out = subprocess.run([sys.executable, "-c", _TIMED, root, log], capture_output=True, text=True, check=True)
            seconds, n = out.stdout.split()
            times[name].append(float(seconds))
            samples[name] = int(n)
    for name, t in times.items():
        median = statistics.median(t)
        print(f"{name}: median {median:.3f} s ({min(t):.3f}-{max(t):.3f}) = {samples[name] / median:,.0f} samples/s "
              f"({samples[name]:,} samples)")
    ratio = statistics.median(times["after"]) / statistics.median(times["before"])
    print(f"after / before: {ratio:.2f}")
    path = results.record("log_read_side_by_side",
                          medians_s={f"read and decode, {name}": statistics.median(t) for name, t in times.items()},
                          ratios={"after / before": ratio},
                          parameters={"repeats": args.repeats, "log": args.after[1]})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
