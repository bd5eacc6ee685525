"""Benchmark: the TUI while a plan runs with the simulated IMU streaming at 2 kHz (not a timed test).

Run: python benchmarks/tui_refresh.py [--seconds 25] [--rate-hz 2000] [--refresh-hz 20]
The app runs headless (`App.run_test`, 100x30) on the simulator (SCPI table over
loopback TCP, the IMU's CAN frames on the python-can virtual bus, the live decoder and
the MCAP recorder, exactly as `bench tui --sim`) with the short test plan at
`--rate-hz`; the plan is started and, after `--seconds` of wall time, aborted (or it
ends first). Reports, as medians over 1 s windows: panel refreshes per second (the
app's `refreshes` counter; target >= 10 Hz; the app's timer asks for 20 Hz by default) and the UI
thread's CPU use (`time.thread_time()` sampled in the UI thread); and the IMU frames
lost: frames the simulator sent vs raw CAN frames recorded in the log (`/can/raw`),
and the receiver's counter gaps (target 0).
"""

from __future__ import annotations

import argparse
import asyncio
import statistics
import sys
import tempfile
import time
from pathlib import Path

import results

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))   # tests.helpers


async def measure(app, seconds: float) -> dict:
    from bench.tui.session import SessionError

    samples: list[tuple[float, float, int]] = []       # (wall, UI thread CPU, refreshes), in the UI thread

    def sample() -> None:
        samples.append((time.monotonic(), time.thread_time(), app.refreshes))

    async with app.run_test(size=(100, 30)) as pilot:
        session = app.session
        session.connect()                     # the idle monitor is parked (poll_s): it pumps nothing
        session.start()
        world = session.run.world
        t0 = time.monotonic()
        app.set_interval(1.0, sample)
        sample()
        while session.running and time.monotonic() - t0 < seconds:
            await pilot.pause(0.2)
        aborted = False
        if session.running:
            try:
                session.abort("benchmark time is up")
                aborted = True
            except SessionError:        # the plan ended meanwhile: the run is being solved, nothing to abort
                pass
        deadline = time.monotonic() + 60.0
        while session.running and time.monotonic() < deadline:
            await pilot.pause(0.1)
        wall = time.monotonic() - t0
        run = session.run
        sent = world.can_imu.frames_sent
        stats = run.receiver.stats
        snapshot = app.buffer.snapshot()
        log_path = run.log_path
    return {"samples": samples, "aborted": aborted, "wall_s": wall, "sent": sent, "stats": stats,
            "log_path": log_path, "sim_s": snapshot.run_time_s, "imu_samples_ui": snapshot.imu.samples}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=25.0, help="wall time of the run before it is aborted")
    parser.add_argument("--rate-hz", type=float, default=2000.0, help="simulated IMU sample rate")
    parser.add_argument("--refresh-hz", type=float, default=20.0, help="the app's panel refresh timer (its default)")
    args = parser.parse_args()

    from bench.config.load import parse_config
    from bench.log.reader import read_log
    from bench.tui import create_app
    from tests.helpers.run import config_text

    with tempfile.TemporaryDirectory() as out:
        config = parse_config(config_text(rate_hz=args.rate_hz, dwell_s=3.0), source=f"{out}/bench.toml",
                              base_dir=Path(out))
        # poll_s: the idle monitor never pumps the IMU, so every frame sent belongs to the recorded run
        app = create_app(config=config, sim=True, out_dir=out, auto_connect=False, refresh_hz=args.refresh_hz,
                         poll_s=3600.0)
        r = asyncio.run(measure(app, args.seconds))
        log = read_log(str(r["log_path"]))
        recorded = len(log.read_can_frames().ids)

    s = r["samples"]
    windows = [(b[0] - a[0], b[1] - a[1], b[2] - a[2]) for a, b in zip(s, s[1:])]
    refresh_hz = [n / dt for dt, _, n in windows]
    cpu = [c / dt for dt, c, _ in windows]
    stats = r["stats"]
    lost = r["sent"] - recorded
    print(f"IMU at {args.rate_hz:g} Hz, panel timer {args.refresh_hz:g} Hz: {r['wall_s']:.1f} s wall, "
          f"{r['sim_s']:.0f} s simulated ({'aborted at the time limit' if r['aborted'] else 'plan ended'})")
    print(f"frames: {r['sent']} sent by the simulator, {recorded} recorded in the log -> lost {lost}; "
          f"receiver: {stats.summary()}")
    print(f"samples shown to the UI buffer: {r['imu_samples_ui']} ({r['imu_samples_ui'] / r['wall_s']:,.0f}/s wall)")
    print(f"panel refresh: median {statistics.median(refresh_hz):.1f} Hz, min {min(refresh_hz):.1f} Hz "
          f"over {len(windows)} windows of 1 s (target >= 10 Hz)")
    print(f"UI thread CPU: median {100 * statistics.median(cpu):.1f} %, max {100 * max(cpu):.1f} % of one core")
    ok = lost == 0 and stats.lost_samples == 0 and statistics.median(refresh_hz) >= 10.0
    print("targets " + ("met" if ok else "MISSED"))
    path = results.record("tui_refresh", medians_s={"panel refresh period (1 s windows)":
                                                     1.0 / statistics.median(refresh_hz)},
                          ratios={"UI thread CPU share of one core (median)": statistics.median(cpu),
                                  "frames lost": float(lost)},
                          parameters={"seconds": args.seconds, "rate_hz": args.rate_hz, "refresh_hz": args.refresh_hz})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
