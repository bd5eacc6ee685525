"""Benchmark: `bench evaluate` with 100 runs at all levels for both tables (target < 5 s).

Run: python benchmarks/evaluate_speed.py [--repeats 7]
Prints the median wall time of the whole command (a fresh interpreter each time,
imports included) and of the in-process Monte-Carlo computation alone, side by side.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time

import results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()

    from bench.schedule_design.monte_carlo import builtin_schedules, evaluate

    command = [sys.executable, "-m", "bench.cli", "evaluate", "--runs", "100"]
    whole, core = [], []
    positions, rotations = builtin_schedules()
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        whole.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        evaluate(positions, rotations, runs=100, seed=0)
        core.append(time.perf_counter() - t0)
    med_whole, med_core = statistics.median(whole), statistics.median(core)
    print(f"bench evaluate --runs 100 (whole command): median {med_whole:.3f} s over {args.repeats} "
          f"(min {min(whole):.3f}, max {max(whole):.3f})")
    print(f"Monte-Carlo core in process:               median {med_core * 1e3:.1f} ms "
          f"(min {min(core) * 1e3:.1f}, max {max(core) * 1e3:.1f})")
    print(f"core / whole: {med_core / med_whole:.3f}; target whole < 5 s: {'met' if med_whole < 5 else 'MISSED'}")
    path = results.record("evaluate_speed", medians_s={"bench evaluate --runs 100, whole command": med_whole,
                                                        "Monte-Carlo core in process": med_core},
                          ratios={"core / whole": med_core / med_whole}, parameters={"repeats": args.repeats})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
