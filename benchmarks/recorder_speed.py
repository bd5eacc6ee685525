"""Benchmark: the MCAP recorder and the log reader (targets: >= 20,000 frames/s, >= 1,000,000 samples/s).

Run: python benchmarks/recorder_speed.py [--frames 2000000] [--repeats 3] [--dir /tmp]
Records >= 2,000,000 raw CAN frames of the default classic layout (7 frames per sample,
so ~285,700 samples are also written to /imu/samples) through `McapRecorder` in
realistic batches of 70..700 frames (with the matching decoded sample blocks, a table
state every 50 samples and an event every 10,000), on one thread; the python-can
messages are built before the clock starts. Prints medians over the repeats of:
- recording: frames/s and samples/s, including `close()` (summary written);
- the zero-loss check: the file read back has every frame, bytes and timestamps identical;
- reading: `read_log` + `RunLog.imu_samples` (samples/s), the decode alone, and the ratio
  against a plain `mcap` `make_reader(f).iter_messages()` loop over the same file
  (which only yields the messages, undecoded).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

import can
import numpy as np
import results

from bench.log.events import make_event
from bench.log.reader import read_log
from bench.log.recorder import McapRecorder
from drivers.imu import ImuEncoder, ImuSampleBlock, decode_frames, default_layout
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState

RECORD_TARGET, READ_TARGET = 20_000, 1_000_000
RATE_HZ = 1000.0
BATCH_SAMPLES = (10, 20, 50, 100)   # x 7 frames: 70..700 frames per on_can_frames call


def build(n_frames: int):
    layout = default_layout()
    n = -(-n_frames // len(layout.messages))
    rng = np.random.default_rng(0)
    frames = ImuEncoder(layout).encode(np.arange(n), rng.normal(0, 3000, (n, 3)), rng.normal(0, 40, (n, 3)))
    # the frames of sample k arrive within its 1 ms period, in order
    times = (frames.sample + 1) / RATE_HZ + (np.arange(len(frames)) % 7) * 1e-5
    data = frames.data
    msgs = [can.Message(timestamp=t, arbitration_id=i, is_extended_id=False, data=data[k].tobytes())
            for k, (t, i) in enumerate(zip(times.tolist(), frames.ids.tolist()))]
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, times, layout=layout, rate_hz=RATE_HZ)
    assert stats.samples == n
    return layout, frames, times, msgs, block


def state(t: float) -> TableState:
    axis = AxisState(12.5, 0.0, AxisMode.POSITION, AxisStatus.ENABLED | AxisStatus.IN_POSITION)
    return TableState(t, (axis, axis, axis))


def record(path: str, msgs, block) -> float:
    n = len(block)
    t0 = time.perf_counter()
    rec = McapRecorder(path, metadata={"run": {"run_id": "bench", "mode": "benchmark"}})
    s = 0
    k = 0
    next_state, next_event = 0, 0
    while s < n:
        m = min(BATCH_SAMPLES[k % len(BATCH_SAMPLES)], n - s)
        k += 1
        rec.on_can_frames(msgs[7 * s:7 * (s + m)])
        rec.on_imu(ImuSampleBlock(block.counter[s:s + m], block.receive_time_s[s:s + m], block.gyro_counts[s:s + m],
                                  block.acc_counts[s:s + m], block.temperature_c[s:s + m], block.status[s:s + m],
                                  block.rate_hz))
        s += m
        t = float(block.receive_time_s[s - 1])
        if s >= next_state:
            rec.on_table_state(state(t))
            next_state += 50
        if s >= next_event:
            rec.on_event(make_event(t, "info", f"sample {s}", data={"samples": s}))
            next_event += 10_000
    rec.close()
    elapsed = time.perf_counter() - t0
    assert rec.frames_written == len(msgs) and rec.samples_written == n
    return elapsed


def check_lossless(path: str, frames, times) -> None:
    log = read_log(path)
    n = len(frames)
    assert log.scan().complete, log.scan().damage
    read = log.read_can_frames()
    assert len(read.ids) == n, f"{len(read.ids)} frames read, {n} written"
    assert np.array_equal(read.ids, frames.ids.astype(np.uint32))
    assert np.array_equal(read.lengths, frames.lengths)
    assert np.array_equal(read.data[:, :8], frames.data[:, :8]) and not read.data[:, 8:].any()
    assert np.array_equal(log.read_can_timestamps_s(), times)


def read(path: str, layout) -> tuple[float, float, int]:
    t0 = time.perf_counter()
    log = read_log(path)
    t1 = time.perf_counter()
    block, stats = log.imu_samples(layout, RATE_HZ)
    t2 = time.perf_counter()
    assert stats.lost_samples == 0 and stats.frame_faults == 0
    return t2 - t0, t2 - t1, len(block)


def plain_mcap(path: str) -> float:
    from mcap.reader import make_reader
    t0 = time.perf_counter()
    with open(path, "rb") as f:
        for _ in make_reader(f).iter_messages():
            pass
    return time.perf_counter() - t0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=2_000_000)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--dir", default=None, help="where to write the log (default: a temporary directory)")
    args = parser.parse_args()

    t = time.perf_counter()
    layout, frames, times, msgs, block = build(args.frames)
    print(f"classic layout, {len(msgs):,} frames = {len(block):,} samples in batches of "
          f"{min(BATCH_SAMPLES) * 7}..{max(BATCH_SAMPLES) * 7} frames; built in {time.perf_counter() - t:.1f} s; "
          f"{args.repeats} repeats")
    ok = True
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        path = os.path.join(tmp, "bench.mcap")
        rec_s, read_s, decode_s, plain_s = [], [], [], []
        for _ in range(args.repeats):
            rec_s.append(record(path, msgs, block))
        size = os.path.getsize(path)
        check_lossless(path, frames, times)
        print(f"zero loss: {len(msgs):,} frames read back, ids, bytes and timestamps identical; "
              f"file {size / 1e6:.1f} MB")
        for _ in range(args.repeats):
            total, decode, n = read(path, layout)
            read_s.append(total)
            decode_s.append(decode)
            plain_s.append(plain_mcap(path))

    rec_med = statistics.median(rec_s)
    frame_rate = len(msgs) / rec_med
    ok &= frame_rate >= RECORD_TARGET
    print(f"record: median {rec_med:.2f} s: {frame_rate:,.0f} frames/s + {len(block) / rec_med:,.0f} samples/s "
          f"(min {min(rec_s):.2f} s, max {max(rec_s):.2f} s); target {RECORD_TARGET:,} frames/s: "
          f"ratio {frame_rate / RECORD_TARGET:.1f} {'met' if frame_rate >= RECORD_TARGET else 'MISSED'}")
    read_med, decode_med, plain_med = (statistics.median(x) for x in (read_s, decode_s, plain_s))
    read_rate = len(block) / read_med
    ok &= read_rate >= READ_TARGET
    print(f"read: read_log + imu_samples median {read_med:.2f} s: {read_rate:,.0f} samples/s "
          f"({len(msgs) / read_med:,.0f} frames/s); target {READ_TARGET:,} samples/s: ratio "
          f"{read_rate / READ_TARGET:.2f} {'met' if read_rate >= READ_TARGET else 'MISSED'}")
    print(f"      of which imu_samples (bulk decode_frames) {decode_med:.2f} s: "
          f"{len(block) / decode_med:,.0f} samples/s; read_log alone {read_med - decode_med:.2f} s: "
          f"{len(block) / (read_med - decode_med):,.0f} samples/s")
    print(f"plain mcap make_reader().iter_messages() (undecoded): median {plain_med:.2f} s; "
          f"read_log + decode is {plain_med / read_med:.1f}x its speed")
    path = results.record("recorder_speed", medians_s={
        f"record {len(msgs):,} frames to MCAP": rec_med, "read_log + imu_samples": read_med,
        "imu_samples alone (bulk decode_frames)": decode_med, "plain mcap iter_messages (undecoded)": plain_med},
        ratios={"recorded frames/s / target": frame_rate / RECORD_TARGET,
                "read samples/s / target": read_rate / READ_TARGET,
                "plain mcap time / read_log + decode time": plain_med / read_med},
        parameters={"frames": args.frames, "repeats": args.repeats})
    print(f"figures written to {path}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
