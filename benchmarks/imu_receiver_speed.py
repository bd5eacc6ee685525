"""Benchmark: the live IMU receiver at live batch sizes, two checkouts of the code side by side.

Run: python benchmarks/imu_receiver_speed.py [--before REF|ROOT] [--after ROOT] [--repeats 5]
     [--batches 7,70,300,440,700,1400,2978,5956] [--frames 60000]

`--before` is a checkout's root folder or a git ref of this repository (its `drivers/` is extracted
with `git archive` into a temporary folder; default 24a7f20, the last commit with the frame-at-a-time
assembler); `--after` is a root (default: this checkout). Every repeat runs both in fresh processes,
alternating, one thread each. A process times `ImuReceiver.poll()` (the hardware path: frames mapped
onto the run clock, error and remote frames set aside, decoded into sample arrays) on a bus that hands
over exactly `batch` frames per poll the way the bench's SLCAN reader does (`recv` gives the first frame,
`drain_messages` the rest); the frames, classic and packed layouts in order with nothing lost, are built
before the clock starts. Prints per batch size the median CPU time per poll (the polling thread's
`time.thread_time`, so that other load on the machine does not count; median over the repeats of each
process's median), frames/s at that cost, and the ratio before / after.

Live batch sizes (what one `poll` receives): the sequencer polls every `imu_poll_s` = `move_poll_s` =
0.05 s, so a poll takes rate x frames per sample x 0.05 s: 70 (200 Hz classic), 300 (2 kHz packed),
440 (a full 1 Mbit/s classic bus, ~8,800 frames/s), 700 (2 kHz classic, simulated); the TUI's idle
monitor polls every 0.1 s (1,400 at 2 kHz classic); the IMU check polls in a tight loop, so its batches
are as small as what arrived since the last read (a sample: 7). The SLCAN bulk reader hands over what
one 64 KiB read of the port held (2,978 classic frames of 22 bytes) and a poll does at most two reads
(`recv`, then `drain_messages`): 5,956 is the most a poll gets from it.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tarfile
import tempfile
from io import BytesIO
from pathlib import Path

from results import record

REPO = Path(__file__).resolve().parents[1]

_TIMED = r'''
import json, statistics, sys, time
sys.path.insert(0, sys.argv[1])
import can
import numpy as np
import drivers
from drivers.imu import EXTENDED_ID_FLAG, ImuEncoder, default_layout, default_packed_layout
from drivers.imu.receiver import ImuReceiver

batches, n_frames = [int(b) for b in sys.argv[2].split(",")], int(sys.argv[3])


class BatchBus(can.BusABC):
    """Hands over `batch` frames per poll: the first by `recv`, the rest by `drain_messages`."""

    def __init__(self, messages, batch):
        self.channel_info = "benchmark"
        self._messages, self._batch, self._at, self._end = messages, batch, 0, 0
        super().__init__(channel="benchmark")

    def _recv_internal(self, timeout):
        if self._at >= len(self._messages):
            return None, False
        self._end = min(self._at + self._batch, len(self._messages))
        self._at += 1
        return self._messages[self._at - 1], False

    def drain_messages(self, limit=None):
        out = self._messages[self._at:self._end]
        self._at = self._end
        return out

    def send(self, msg, timeout=None):
        raise NotImplementedError("a receive-only bus")


def messages(layout, n):
    per = len(layout.messages)
    count = -(-n // per)
    rng = np.random.default_rng(0)
    frames = ImuEncoder(layout).encode(np.arange(count), rng.normal(0, 3000, (count, 3)),
                                       rng.normal(0, 40, (count, 3)), 21.5, 0)
    out = []
    for i in range(len(frames)):
        key, data = frames.frame(i)
        out.append(can.Message(arbitration_id=key & ~EXTENDED_ID_FLAG, is_extended_id=bool(key & EXTENDED_ID_FLAG),
                               data=data, timestamp=1.8e9 + i * 1e-4))
    return out


def run(layout, msgs, batch):
    bus = BatchBus(msgs, batch)
    receiver = ImuReceiver(bus, layout, 1000.0, time_base=time.monotonic)
    times, samples = [], 0
    clock = time.thread_time   # CPU time of this thread: what a poll costs, whatever else loads the machine
    while receiver.frames_received < len(msgs):
        t = clock()
        block = receiver.poll(timeout_s=0.0)
        times.append(clock() - t)
        samples += len(block)
    samples += len(receiver.flush())
    stats = receiver.stats
    bus.shutdown()
    assert stats.frame_faults == 0 and stats.lost_samples == 0 and samples == len(msgs) // len(layout.messages)
    return times


out = {"drivers": drivers.__file__}
for name, layout in (("classic", default_layout()), ("packed", default_packed_layout())):
    for batch in batches:
        n = max(n_frames, 20 * batch)
        n -= n % len(layout.messages)
        run(layout, messages(layout, min(n, 20 * batch)), batch)          # warm up
        times = run(layout, messages(layout, n), batch)
        out[f"{name} {batch}"] = [statistics.median(times), sum(times), n]
print(json.dumps(out))
'''


def checkout(spec: str, tmp: Path) -> str:
    """A root folder to import `drivers` from: `spec` itself if a folder, else the ref's `drivers/` extracted."""
    if Path(spec).is_dir():
        return str(Path(spec).resolve())
    archive = subprocess.run(["git", "-C", str(REPO), "archive", spec, "drivers"], capture_output=True, check=True)
    root = tmp / spec.replace("/", "_")
    with tarfile.open(fileobj=BytesIO(archive.stdout)) as tar:
        tar.extractall(root, filter="data")
    return str(root)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", default="24a7f20", help="a checkout's root or a git ref (default 24a7f20)")
    parser.add_argument("--after", default=str(REPO), help="a checkout's root (default: this one)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--batches", default="7,70,300,440,700,1400,2978,5956")
    parser.add_argument("--frames", type=int, default=60_000, help="frames per measurement (at least 20 polls)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        roots = {"before": checkout(args.before, Path(tmp)), "after": checkout(args.after, Path(tmp))}
        results: dict[str, list[dict]] = {k: [] for k in roots}
        for _ in range(args.repeats):
            for name, root in roots.items():
                done = subprocess.run([sys.executable, "-c", _TIMED, root, args.batches, str(args.frames)],
                                      capture_output=True, text=True, cwd=tmp)
                if done.returncode:
                    sys.exit(f"the {name} process failed:\n{done.stderr}")
                results[name].append(json.loads(done.stdout))
    for name in roots:
        print(f"{name}: {args.before if name == 'before' else args.after} "
              f"(drivers from {results[name][0]['drivers']})")
    print(f"{args.repeats} repeats, one process per checkout and repeat, alternating; median CPU time per poll")
    print(f"{'layout, frames per poll':<26}{'before':>12}{'after':>12}{'before/after':>14}"
          f"{'after frames/s':>16}{'after min-max':>22}")
    medians_s: dict[str, float] = {}
    ratios: dict[str, float] = {}
    for key in (k for k in results["after"][0] if k != "drivers"):
        med = {name: statistics.median(r[key][0] for r in runs) for name, runs in results.items()}
        medians_s[f"{key} frames per poll: CPU time per poll, after"] = med["after"]
        medians_s[f"{key} frames per poll: CPU time per poll, before"] = med["before"]
        ratios[f"{key} frames per poll: before / after"] = med["before"] / med["after"]
        spread = [r[key][0] for r in results["after"]]
        batch = int(key.split()[1])
        print(f"{key:<26}{med['before'] * 1e6:>10.1f}us{med['after'] * 1e6:>10.1f}us"
              f"{med['before'] / med['after']:>14.2f}{batch / med['after']:>16,.0f}"
              f"{min(spread) * 1e6:>11.1f}-{max(spread) * 1e6:.1f}us")
    path = record("imu_receiver_speed", medians_s=medians_s, ratios=ratios, parameters={
        "before": args.before, "after": args.after, "repeats": args.repeats, "batches": args.batches,
        "frames": args.frames})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
