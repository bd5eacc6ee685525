"""Benchmark: the Allan deviation of six channels of a long static recording (issue 17, "bench noise").

Target: the overlapping Allan deviation of 6 channels of an 8 h, 1 kHz recording (28.8 M samples
per channel), the log read included, in under 10 s on this machine (allan_variance_ros: 215 s
for an 8 h bag).

Run: python tests/benchmarks/noise_speed.py [--hours 8] [--rate-hz 1000] [--repeats 3]
                                            [--log-hours 1] [--cache DIR] [--rebuild]

1. In memory: six channels of `--hours` at `--rate-hz` (white noise plus a random walk on a large
   offset, float64), octave-spaced taus. Timed side by side in one run, the repeats interleaved:
   `bench.noise.allan.allan_curves` (both cores: each channel's record split over two threads) and `allantools.oadev`
   (data_type "freq", the same taus, one channel after the other: it is single-threaded). Prints
   the medians, their ratio and the largest relative difference of the two at any tau.
2. From a log: a static-noise log of `--log-hours` at `--rate-hz` (the simulated IMU, classic CAN
   layout, 7 frames per sample, in batches of 100 samples as a run records them; /imu/samples,
   which a read for the noise leaves compressed, is not written), built once into the cache
   (default <system temp>/turntable-bench-noise, `--rebuild` writes it again). Timed: what
   `bench noise LOG` does short of writing the reports: `bench.noise.from_log.static_record` (read
   the log, decode every frame, cut the dwell) and `bench.noise.result.analyse_blocks` (scale to deg/h
   and ug block by block into the phase accumulator, Allan deviation and fits). Median of the repeats;
   scaled linearly to 8 h.
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

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


def in_memory(args) -> float:
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
    print(f"bench allan_curves (2 threads): median {mine:.2f} s (min {min(ours):.2f}, max {max(ours):.2f}) "
          f"for {len(taus)} taus per channel = {6 * n / mine / 1e6:.1f} M samples/s")
    if theirs:
        ref = statistics.median(theirs)
        print(f"allantools.oadev (6 channels one after the other): median {ref:.2f} s (min {min(theirs):.2f}, "
              f"max {max(theirs):.2f}); bench is {ref / mine:.2f}x as fast; largest relative difference at any "
              f"tau {worst:.2e}")
    return mine


# -- the static-noise log --------------------------------------------------------------------------------------
def log_path(cache: Path, args) -> Path:
    return cache / f"static-{args.log_hours:g}h-{args.rate_hz:g}hz-v{LOG_VERSION}.mcap"


def write_log(path: Path, hours: float, rate_hz: float) -> None:
    """A simulated static-noise recording written as a run writes it (metadata, events, raw CAN batches)."""
    from bench.config.load import parse_config
    from bench.log.format import record_dtype
    from bench.log.recorder import McapRecorder
    from bench.model.earth import Site
    from bench.plan.events import Event
    from bench.plan.steps import DwellStep, step_to_dict
    from bench.run.runner import compile_from_config
    from bench.sim.imu import SimImu
    from bench.sim.table import SimTable
    from drivers.imu import ImuEncoder, default_layout

    text = f"""format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.27
[table]
url = "sim"
dialect = "scpi"
[imu]
interface = "virtual"
channel = "noise-speed"
rate_hz = {rate_hz}
[plan]
positions = "static-noise"
dwell_s = {hours * 3600.0}
[sim]
seed = 0
"""
    config = parse_config(text, source=str(path.with_suffix(".toml")))
    dwell = next(s for s in compile_from_config(config).steps if isinstance(s, DwellStep))
    layout = default_layout()
    encoder = ImuEncoder(layout)
    imu = SimImu(config.sim.imu, config.sim.noise, rate_hz=rate_hz, seed=0)
    table = SimTable(Site(latitude_deg=30.27))
    n_total = int(round(hours * 3600.0 * rate_hz))
    tmp = path.with_suffix(".partial")
    metadata = {"run": {"run_id": "noise-speed", "mode": "simulator"},
                "config": {"toml": text, "path": "<noise-speed benchmark>"},
                "imu": {"model": "simulated FOG IMU", "serial": "SIM-0001", "rate_hz": str(rate_hz),
                        "interface": "virtual", "channel": "noise-speed", "dbc": config.imu.dbc.name}}
    dtype = record_dtype(("data", "u1", (8,)))
    per_batch = 100                              # samples per /can/raw message (700 frames)
    with McapRecorder(str(tmp), metadata=metadata) as rec:
        rec.on_event(Event(0.0, "step_started", "P01 dwell", step_index=dwell.index, step_unit="P01",
                           data={"step": step_to_dict(dwell)}))
        done, t_end = 0, 0.0
        while done < n_total:
            t_end = min(t_end + 600.0, n_total / rate_hz)
            block = imu.generate(table, t_end)
            frames = encoder.encode(block.counter, block.gyro_counts, block.acc_counts)
            records = np.zeros(len(frames), dtype=dtype)
            per = len(layout.messages)
            records["t"] = block.time_s[frames.sample] + (np.arange(len(frames)) % per) * 1e-6
            records["id"] = frames.ids
            records["len"] = frames.lengths
            records["data"] = frames.data
            step = per_batch * per
            for lo in range(0, len(records), step):
                batch = records[lo:lo + step]
                rec.on_encoded_can_frames(batch.tobytes(), len(batch), float(batch["t"][-1]))
            done += len(block)
        rec.on_event(Event(t_end, "step_finished", "P01 dwell done", step_index=dwell.index, step_unit="P01",
                           data={"step": step_to_dict(dwell), "counter_first": 0, "counter_last": n_total - 1,
                                 "samples": n_total}))
    os.replace(tmp, path)


def from_log(args, cache: Path) -> tuple[float, float]:
    from bench.noise.from_log import static_record
    from bench.noise.result import analyse_blocks

    path = log_path(cache, args)
    if args.rebuild or not path.exists():
        t0 = time.perf_counter()
        cache.mkdir(parents=True, exist_ok=True)
        write_log(path, args.log_hours, args.rate_hz)
        print(f"wrote {path} in {time.perf_counter() - t0:.1f} s")
    else:
        print(f"reusing {path}")
    totals, reads = [], []
    n = 0
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        record = static_record(path)
        t1 = time.perf_counter()
        analyse_blocks(record.blocks(), record.rate_hz, capacity=len(record))
        totals.append(time.perf_counter() - t0)
        reads.append(t1 - t0)
        n = len(record)
        del record
    total, read = statistics.median(totals), statistics.median(reads)
    scale = 8.0 / args.log_hours
    print(f"log: {n:,} samples per channel = {7 * n:,} CAN frames, {path.stat().st_size / 1e6:.0f} MB")
    print(f"static_record + analyse (bench noise LOG without the reports): median {total:.2f} s (min "
          f"{min(totals):.2f}, max {max(totals):.2f}), of which reading and decoding the log {read:.2f} s "
          f"({n / read:,.0f} samples/s) and the Allan deviation and fits {total - read:.2f} s")
    print(f"scaled to 8 h at this rate ({scale:g}x): {total * scale:.1f} s (read {read * scale:.1f} s); "
          f"target {TARGET_S:g} s: {'met' if total * scale < TARGET_S else 'MISSED'}")
    return total, read


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hours", type=float, default=8.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--log-hours", type=float, default=1.0, help="length of the log to read (0: skip)")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "turntable-bench-noise")
    parser.add_argument("--rebuild", action="store_true")
    parser.add_argument("--skip-memory", action="store_true", help="only the log part")
    args = parser.parse_args()
    print(f"machine: {os.cpu_count()} cores, load average {' '.join(f'{v:.2f}' for v in os.getloadavg())} "
          "(other work on the machine slows both sides)")
    if not args.skip_memory:
        in_memory(args)
    if args.log_hours > 0:
        from_log(args, args.cache)
    print(f"load average at the end: {' '.join(f'{v:.2f}' for v in os.getloadavg())}")


if __name__ == "__main__":
    main()
