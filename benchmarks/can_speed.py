"""Benchmark: IMU over CAN ingest and bulk decode (targets: >= 50,000 and >= 2,000,000 frames/s).

Run: python benchmarks/can_speed.py [--repeats 5] [--live-frames 70000] [--bulk-frames 1000000]
Prints medians over the repeats, on one core (everything runs in one thread):
- ingest: `ImuReceiver.poll()` draining a python-can virtual bus pre-filled with frames of
  the default classic layout (receive + length/CRC check + assemble + sample arrays out,
  raw frames handed to a logging callback); the bus is filled before the clock starts;
- the stream decoder alone on the same messages, in polls of 10,000 (no bus);
- bulk decode (`decode_frames`) of recorded frames held in arrays;
and the CAN FD layout's bulk rate for reference.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time

import can
import numpy as np
import results

from drivers.imu import (
    ImuEncoder,
    StreamDecoder,
    decode_frames,
    default_fd_layout,
    default_layout,
    frames_from_messages,
)
from drivers.imu.receiver import ImuReceiver

LIVE_TARGET, BULK_TARGET = 50_000, 2_000_000


def recorded(n_frames: int, layout) -> tuple:
    per_sample = len(layout.messages)
    n = -(-n_frames // per_sample)
    rng = np.random.default_rng(0)
    frames = ImuEncoder(layout).encode(np.arange(n), rng.normal(0, 3000, (n, 3)), rng.normal(0, 40, (n, 3)))
    return frames, np.arange(len(frames)) * 1e-4


def messages(frames, times) -> list[can.Message]:
    return [can.Message(arbitration_id=int(frames.ids[i]), data=frames.data[i, :frames.lengths[i]].tobytes(),
                        is_extended_id=False, timestamp=float(times[i])) for i in range(len(frames))]


def bench_ingest(msgs: list[can.Message], repeats: int) -> list[float]:
    rates = []
    for r in range(repeats):
        channel = f"can_speed_{r}"
        tx, rx = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
        try:
            for m in msgs:
                tx.send(m)
            logged: list[can.Message] = []
            receiver = ImuReceiver(rx, rate_hz=1000.0, on_frames=logged.extend)
            t0 = time.perf_counter()
            samples = 0
            while True:
                block = receiver.poll(max_frames=10_000, timeout_s=0.0)
                samples += len(block)
                if receiver.frames_received >= len(msgs):
                    break
            rates.append(len(msgs) / (time.perf_counter() - t0))
            assert receiver.stats.frame_faults == 0 and len(logged) == len(msgs) and samples > 0
        finally:
            tx.shutdown()
            rx.shutdown()
    return rates


def bench_decoder(msgs: list[can.Message], repeats: int) -> list[float]:
    rates = []
    for _ in range(repeats):
        decoder = StreamDecoder(default_layout(), 1000.0)
        t0 = time.perf_counter()
        for a in range(0, len(msgs), 10_000):
            decoder.feed(*frames_from_messages(msgs[a:a + 10_000], width=None))
            decoder.take_block()
        rates.append(len(msgs) / (time.perf_counter() - t0))
    return rates


def bench_bulk(frames, times, layout, repeats: int) -> list[float]:
    decode_frames(frames.ids[:1000], frames.data[:1000], frames.lengths[:1000], times[:1000], layout=layout)
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        block, stats = decode_frames(frames.ids, frames.data, frames.lengths, times, layout=layout)
        rates.append(len(frames) / (time.perf_counter() - t0))
        assert stats.frame_faults == 0 and len(block) == stats.samples
    return rates


def line(label: str, rates: list[float], target: float | None = None) -> str:
    med = statistics.median(rates)
    text = f"{label:<44} median {med:>12,.0f} frames/s (min {min(rates):,.0f}, max {max(rates):,.0f})"
    if target:
        text += f"; target {target:,.0f}: ratio {med / target:.2f} {'met' if med >= target else 'MISSED'}"
    return text


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--live-frames", type=int, default=70_000)
    parser.add_argument("--bulk-frames", type=int, default=1_000_000)
    args = parser.parse_args()

    layout = default_layout()
    live_frames, live_times = recorded(args.live_frames, layout)
    msgs = messages(live_frames, live_times)
    print(f"classic layout, {len(layout.messages)} frames per sample; {len(msgs):,} frames live, "
          f"{args.repeats} repeats")
    rates = {"ingest: virtual bus -> ImuReceiver.poll": bench_ingest(msgs, args.repeats)}
    print(line("ingest: virtual bus -> ImuReceiver.poll", rates["ingest: virtual bus -> ImuReceiver.poll"],
               LIVE_TARGET))
    rates["stream decoder alone (StreamDecoder.feed)"] = bench_decoder(msgs, args.repeats)
    print(line("stream decoder alone (StreamDecoder.feed)", rates["stream decoder alone (StreamDecoder.feed)"]))
    bulk_frames, bulk_times = recorded(args.bulk_frames, layout)
    rates["bulk decode_frames"] = bench_bulk(bulk_frames, bulk_times, layout, args.repeats)
    print(line(f"bulk decode_frames, {len(bulk_frames):,} frames", rates["bulk decode_frames"], BULK_TARGET))
    fd = default_fd_layout()
    fd_frames, fd_times = recorded(args.bulk_frames // 4, fd)
    rates["bulk decode_frames, CAN FD"] = bench_bulk(fd_frames, fd_times, fd, args.repeats)
    print(line(f"bulk decode_frames, CAN FD, {len(fd_frames):,} frames", rates["bulk decode_frames, CAN FD"]))
    # the figures file holds seconds per frame (the medians' inverse) and each target's ratio
    path = results.record("can_speed", medians_s={f"{name}: one frame": 1.0 / statistics.median(r)
                                                   for name, r in rates.items()},
                          ratios={"ingest frames/s / target":
                                  statistics.median(rates["ingest: virtual bus -> ImuReceiver.poll"]) / LIVE_TARGET,
                                  "bulk frames/s / target":
                                  statistics.median(rates["bulk decode_frames"]) / BULK_TARGET},
                          parameters={"repeats": args.repeats, "live_frames": args.live_frames,
                                      "bulk_frames": args.bulk_frames})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
