"""Benchmark: the Allan deviation of six channels of a long static recording (issue 17, "bench noise").

Target: the overlapping Allan deviation of 6 channels of an 8 h, 1 kHz recording (28.8 M samples
per channel), the log read included, in under 10 s on this machine (allan_variance_ros: 215 s
for an 8 h bag).

Run: python benchmarks/noise_speed.py [--hours 8] [--rate-hz 1000] [--repeats 3]
                                            [--log-hours 1] [--layout packed|classic] [--cache DIR]
                                            [--rebuild] [--whole] [--skip-memory] [--allantools-on-log]

1. In memory: six channels of `--hours` at `--rate-hz` (white noise plus a random walk on a large
   offset, float64), octave-spaced taus. Timed side by side in one run, the repeats interleaved:
   `bench.noise.allan.allan_curves` (both cores: each channel's record split over two threads) and
   `allantools.oadev` (data_type "freq", the same taus, one channel after the other: it is
   single-threaded). Prints the medians, their ratio and the largest relative difference at any tau.
2. From a log: a static-noise log of `--log-hours` at `--rate-hz` (the simulated IMU, quantised counts,
   `--layout`: packed, 3 frames per sample, the default, or classic, 7; in batches of 100 samples as a
   run records them; `tests/helpers/static_log.py`), built once into the cache (default <system
   temp>/turntable-bench-noise, `--rebuild` writes it again). Timed, each repeat in a fresh process
   (its peak resident memory is that route's): what `bench noise LOG` does short of writing the
   reports, `bench.noise.from_log.analyse_log` (frames decoded chunk by chunk into the Allan phase on
   a second thread, then the sums and fits); `--whole` also times the whole-log route it replaced
   (`static_record`: every sample decoded first, then `analyse_blocks`), the repeats interleaved.
   `--allantools-on-log`: the same log's samples (deg/h and ug) through `allantools.oadev` and through
   `allan_curves` in memory, side by side (the "same data" ratio).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import results

from bench.noise.allan import allan_curves, cluster_sizes

TARGET_S = 10.0
LOG_VERSION = 1          # bump when the log's content changes


def synthetic_channels(n: int, seed: int = 0) -> np.ndarray:
    """(n, 6) float64: white noise and a slow random walk on an offset of 1e4 (counts/s-like)."""
    rng = np.random.default_rng(seed)
    data = np.empty((n, 6))
    for k in range(6):
        col = data[:, k]
        col[:] = rng.standard_normal(n)
        col *= 1e-3
        np.cumsum(col, out=col)
        col += rng.standard_normal(n) * 3.0
        col += 1e4 * (k + 1)
    return data


def in_memory(args) -> dict:
    """Times both sides; returns the figures for `results.record` (medians in s, the speed ratio)."""
    n = int(args.hours * 3600 * args.rate_hz)
    t0 = time.perf_counter()
    data = synthetic_channels(n)
    print(f"in memory: 6 channels x {n:,} samples ({args.hours:g} h at {args.rate_hz:g} Hz), made in "
          f"{time.perf_counter() - t0:.1f} s")
    taus = cluster_sizes(n) / args.rate_hz
    ours, theirs, worst = [], [], 0.0
    try:
        import allantools
    except ImportError:
        allantools = None
        print("allantools is not installed (pip install allantools): timing bench's own only")
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        curves = allan_curves(data, args.rate_hz, threads=2)
        ours.append(time.perf_counter() - t0)
        if allantools is not None:
            t0 = time.perf_counter()
            reference = [allantools.oadev(data[:, k], rate=args.rate_hz, data_type="freq", taus=taus)[1]
                         for k in range(6)]
            theirs.append(time.perf_counter() - t0)
            worst = max(worst, max(float(np.max(np.abs(r / c.adev - 1))) for r, c in zip(reference, curves)))
    mine = statistics.median(ours)
    figures: dict = {"medians_s": {"bench allan_curves, 6 channels in memory": mine}, "ratios": {}}
    print(f"bench allan_curves (2 threads): median {mine:.2f} s (min {min(ours):.2f}, max {max(ours):.2f}) "
          f"for {len(taus)} taus per channel = {6 * n / mine / 1e6:.1f} M samples/s")
    if theirs:
        ref = statistics.median(theirs)
        print(f"allantools.oadev (6 channels one after the other): median {ref:.2f} s (min {min(theirs):.2f}, "
              f"max {max(theirs):.2f}); bench is {ref / mine:.2f}x as fast; largest relative difference at any "
              f"tau {worst:.2e}")
        figures["medians_s"]["allantools.oadev, 6 channels in memory"] = ref
        figures["ratios"]["allantools time / bench time (in memory)"] = ref / mine
    return figures


# -- the static-noise log --------------------------------------------------------------------------------------
def log_path(cache: Path, args) -> Path:
    return cache / f"static-{args.log_hours:g}h-{args.rate_hz:g}hz-{args.layout}-v{LOG_VERSION}.mcap"


def write_log(path: Path, hours: float, rate_hz: float, layout_name: str = "packed") -> None:
    """A simulated static-noise recording written as a run writes it (metadata, events, raw CAN batches)."""
    from tests.helpers.static_log import write_static_log

    write_static_log(path, hours * 3600.0, rate_hz, layout_name)


def _one(route: str, path: str) -> dict:
    """One timed route in this (fresh) process: wall and CPU seconds, peak resident MB."""
    import resource

    from bench.noise.from_log import analyse_log, static_record
    from bench.noise.result import analyse_blocks

    t0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
    if route == "stream":
        result, _ = analyse_log(path)
        n = result.n_samples
    else:
        record = static_record(path)
        analyse_blocks(record.blocks(), record.rate_hz, capacity=len(record))
        n = len(record)
    return {"wall": time.perf_counter() - t0, "cpu": time.process_time() - c0, "main_cpu": time.thread_time() - m0,
            "n": n,
            "peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}


def _in_process(route: str, path: Path) -> dict:
    import json
    import subprocess
    import sys

    done = subprocess.run([sys.executable, __file__, "--one", route, str(path)], capture_output=True, text=True,
                          check=True, env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    return json.loads(done.stdout.strip().splitlines()[-1])


def from_log(args, cache: Path) -> None:
    path = log_path(cache, args)
    if args.rebuild or not path.exists():
        t0 = time.perf_counter()
        cache.mkdir(parents=True, exist_ok=True)
        write_log(path, args.log_hours, args.rate_hz, args.layout)
        print(f"wrote {path} in {time.perf_counter() - t0:.1f} s")
    else:
        print(f"reusing {path}")
    routes = ["stream"] + (["whole"] if args.whole else [])
    runs: dict[str, list[dict]] = {r: [] for r in routes}
    for _ in range(args.repeats):
        for route in routes:
            runs[route].append(_in_process(route, path))
            last = runs[route][-1]
            print(f"  {route}: {last['wall']:.2f} s wall, {last['cpu']:.2f} s CPU ({last['main_cpu']:.2f} s of it on "
                  f"the main thread), peak {last['peak_mb']:,.0f} MB, "
                  f"load {os.getloadavg()[0]:.2f}", flush=True)
    n = runs["stream"][0]["n"]
    frames = {"packed": 3, "classic": 7}[args.layout] * n
    print(f"log: {n:,} samples per channel = {frames:,} CAN frames ({args.layout} layout), "
          f"{path.stat().st_size / 1e6:.0f} MB")
    for route, label in (("stream", "bench noise LOG (streamed)"), ("whole", "whole-log route")):
        if route not in runs:
            continue
        walls = [r["wall"] for r in runs[route]]
        wall, peak = statistics.median(walls), max(r["peak_mb"] for r in runs[route])
        print(f"{label}: median {wall:.2f} s (min {min(walls):.2f}, max {max(walls):.2f}), CPU median "
              f"{statistics.median(r['cpu'] for r in runs[route]):.2f} s, peak {peak:,.0f} MB; "
              f"scaled to 8 h at this rate: {wall * 8.0 / args.log_hours:.1f} s (target {TARGET_S:g} s: "
              f"{'met' if wall * 8.0 / args.log_hours < TARGET_S else 'MISSED'})")
    if args.allantools_on_log:
        on_log(path, args)


def on_log(path: Path, args) -> None:
    """allantools and `allan_curves` side by side on the log's own samples (deg/h, ug)."""
    from bench.noise.from_log import static_record

    record = static_record(path)
    data = record.data
    del record
    taus = cluster_sizes(len(data)) / args.rate_hz
    import allantools

    ours, theirs, worst = [], [], 0.0
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        curves = allan_curves(data, args.rate_hz, threads=2)
        ours.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        reference = [allantools.oadev(data[:, k], rate=args.rate_hz, data_type="freq", taus=taus)[1]
                     for k in range(6)]
        theirs.append(time.perf_counter() - t0)
        worst = max(worst, max(float(np.max(np.abs(r / c.adev - 1))) for r, c in zip(reference, curves)))
        print(f"  on the log's samples: allan_curves {ours[-1]:.2f} s, allantools {theirs[-1]:.2f} s, load "
              f"{os.getloadavg()[0]:.2f}", flush=True)
    mine, ref = statistics.median(ours), statistics.median(theirs)
    print(f"the log's {len(data):,} samples x 6 in memory: allan_curves median {mine:.2f} s, allantools.oadev "
          f"median {ref:.2f} s ({ref / mine:.2f} x); largest relative difference at any tau {worst:.2e}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--log-hours", type=float, default=1.0, help="length of the log to read (0: skip)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "turntable-bench-noise")
    parser.add_argument("--rebuild", action="store_true")
    parser.add_argument("--layout", choices=("packed", "classic"), default="packed",
                        help="CAN layout of the log (default packed: 3 frames per sample)")
    parser.add_argument("--skip-memory", action="store_true", help="only the log part")
    parser.add_argument("--whole", action="store_true", help="also time the whole-log route, interleaved")
    parser.add_argument("--allantools-on-log", action="store_true",
                        help="allantools and allan_curves on the log's samples, side by side")
    parser.add_argument("--one", nargs=2, metavar=("ROUTE", "LOG"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.one:
        import json

        print(json.dumps(_one(*args.one)))
        return
    print(f"machine: {os.cpu_count()} cores, load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} "
          "(other work on the machine slows both sides)")
    if not args.skip_memory:
        figures = in_memory(args)
        path = results.record("noise_speed", **figures, parameters={"hours": args.hours, "rate_hz": args.rate_hz,
                                                                    "repeats": args.repeats},
                              note="the in-memory part (1.); the log part prints its figures only")
        print(f"figures written to {path}")
    if args.log_hours > 0:
        from_log(args, args.cache)
    print(f"load average at the end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
