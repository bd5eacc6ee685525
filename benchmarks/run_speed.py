"""Benchmark: the full default simulated plan (`bench run --sim`) in wall and CPU time (target < 8 s wall).

Run: python benchmarks/run_speed.py [--repeats 3] [--against DIR]
Each repeat runs `bench run --sim --no-db --quiet --out TMP` as a fresh process: optimal-24 +
optimal-5s6r, dwell 60 s, settle 5 s, turns at 10 deg/s, 1 revolution, IMU at 200 Hz,
noise on, every sample through the SCPI driver over loopback TCP, the python-can
virtual bus, the live decoder and the MCAP recorder; then the solve from the log.
Prints each run's wall time, CPU time (user + system, from `resource.getrusage` of the
children) and the load average when it ended, then the medians, the simulated time and
CAN frames the log holds, and checks from the log that no frame was lost.

`--against DIR`: also run the code checked out in DIR (e.g. `git worktree add /tmp/base 26d4a3c`)
the same way, alternating the two run by run (a load that comes and goes hits both alike); prints
both medians, their ratios, and whether the two results' coefficients, uncertainty budgets,
residuals and quality figures are the same bit for bit (the simulator is seeded; run ids and
times are left out).
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import results

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
#: result sections that must not depend on the code's speed (the run section names ids and times)
SAME_SECTIONS = ("coefficients", "residuals", "quality", "temperature", "sim_truth")


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def run_once(checkout: str, out: str) -> tuple[float, float, int]:
    """One `bench run --sim` of the code in `checkout` into `out`: (wall s, CPU s, exit code)."""
    command = [sys.executable, "-m", "bench.cli", "run", "--sim", "--no-db", "--quiet", "--out", out]
    cpu0, t0 = _children_cpu_s(), time.perf_counter()
    code = subprocess.run(command, cwd=checkout, stdout=subprocess.DEVNULL).returncode
    return time.perf_counter() - t0, _children_cpu_s() - cpu0, code


def describe_log(out: str, wall_s: float) -> str:
    from bench.log.reader import read_log

    log = read_log(glob.glob(f"{out}/*.mcap")[0])
    with open(glob.glob(f"{out}/*.result.json")[0]) as f:
        result = json.load(f)
    link = result["run"]["imu_link"]
    sim_s = log.events[-1].time_s
    frames = len(log.read_can_frames().ids)
    return (f"{sim_s:.0f} s simulated ({sim_s / wall_s:.0f}x), {frames} CAN frames recorded = "
            f"{frames / wall_s:,.0f} frames/s; link: {link['frames']} received, {link['samples']} samples, "
            f"{link['counter_gaps'] + link['incomplete_samples']} lost; log complete: {log.scan().complete}")


def result_sections(out: str) -> dict:
    with open(glob.glob(f"{out}/*.result.json")[0]) as f:
        result = json.load(f)
    return {k: result.get(k) for k in SAME_SECTIONS}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--against", metavar="DIR", help="another checkout to run alternately (the baseline)")
    args = parser.parse_args()
    checkouts = {"this": HERE}
    if args.against:
        checkouts = {"base": os.path.abspath(args.against), "this": HERE}
    figures: dict[str, list[tuple[float, float]]] = {name: [] for name in checkouts}
    sections: dict[str, dict] = {}
    failed = False
    for k in range(args.repeats):
        for name, checkout in checkouts.items():
            with tempfile.TemporaryDirectory() as out:
                wall, cpu, code = run_once(checkout, out)
                load = os.getloadavg()
                figures[name].append((wall, cpu))
                print(f"{name} #{k + 1}: exit {code}: {wall:.1f} s wall, {cpu:.1f} s CPU, load "
                      f"{load[0]:.2f} {load[1]:.2f} {load[2]:.2f}; " + describe_log(out, wall), flush=True)
                failed |= code != 0
                sections.setdefault(name, result_sections(out))
    medians = {name: (statistics.median(w for w, _ in f), statistics.median(c for _, c in f))
               for name, f in figures.items()}
    for name, (wall, cpu) in medians.items():
        print(f"{name}: median over {args.repeats}: {wall:.2f} s wall, {cpu:.2f} s CPU")
    wall, cpu = medians["this"]
    print(f"target < 8 s wall: {'met' if wall < 8 else 'MISSED'}")
    if "base" in medians:
        base_wall, base_cpu = medians["base"]
        print(f"ratio this/base: wall {wall / base_wall:.3f} ({base_wall / wall:.2f}x faster), "
              f"CPU {cpu / base_cpu:.3f} ({base_cpu / cpu:.2f}x less)")
        same = sections["base"] == sections["this"]
        differing = [s for s in SAME_SECTIONS if sections["base"][s] != sections["this"][s]]
        print(f"result ({', '.join(SAME_SECTIONS)}) bit for bit the same: {same}"
              + (f" (differ: {', '.join(differing)})" if differing else ""))
        failed |= not same
    ratios = {}
    if "base" in medians:
        ratios = {"wall this/base": wall / base_wall, "CPU this/base": cpu / base_cpu}
    path = results.record("run_speed", medians_s={"bench run --sim, default plan, wall": wall,
                                                  "bench run --sim, default plan, CPU": cpu,
                                                  **({"baseline wall": base_wall, "baseline CPU": base_cpu}
                                                     if "base" in medians else {})},
                          ratios=ratios, parameters={"repeats": args.repeats, "against": args.against or ""})
    print(f"figures written to {path}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
