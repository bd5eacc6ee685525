"""Benchmark: the chamber's state-poll round trip per dialect and link, and the simulated chamber's speed.

Run: python benchmarks/chamber_speed.py [--polls 1000] [--repeats 5]
For each dialect (ascii, modbus) it serves the simulated chamber on 127.0.0.1 (Modbus TCP
for modbus) and on a pty (Modbus RTU at 115200 baud nominal), connects the real driver
through the real transport and times `read_state()` (one MON? for ascii, two register
reads for the default Modbus map); everything in one run, side by side. Prints the
median and 90th percentile per poll in ms (median over repeats). Then it times the
physics alone on a ManualClock: a 40 degC ramp at 1 degC/min followed by a soak, 8 h of
chamber time read once a simulated second, and prints the simulated seconds per wall
second.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.sim.chamber import SimChamber  # noqa: E402
from bench.sim.chamber_server import serve_chamber  # noqa: E402
from drivers.chamber import open_chamber  # noqa: E402
from drivers.clock import ManualClock  # noqa: E402
from tests.helpers.timing import poll_ms  # noqa: E402


def measure_poll(dialect: str, link: str, polls: int) -> tuple[float, float]:
    """(median ms, p90 ms) of `polls` state reads."""
    close, url = serve_chamber(SimChamber(), dialect, link)
    try:
        with open_chamber(url, dialect, timeout_s=1.0) as chamber:
            return poll_ms(chamber.read_state, polls)
    finally:
        close()


def measure_physics(hours: float = 8.0) -> float:
    """Simulated seconds per wall second for `hours` of a ramp and soak read every simulated second."""
    clock = ManualClock()
    sim = SimChamber(clock=clock)
    sim.set_ramp(1.0)
    sim.set_setpoint(-17.0)
    sim.run()
    steps = int(hours * 3600)
    t0 = time.perf_counter()
    for _ in range(steps):
        clock.advance(1.0)
        sim.state()
    return steps / (time.perf_counter() - t0)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--polls", type=int, default=1000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    print(f"chamber state poll round trip, {args.polls} polls x {args.repeats} repeats")
    print(f"{'dialect':<8} {'link':<5} {'median ms':>10} {'p90 ms':>8} {'polls/s':>9}")
    medians_s: dict[str, float] = {}
    for dialect in ("ascii", "modbus"):
        for link in ("tcp", "pty"):
            runs = [measure_poll(dialect, link, args.polls) for _ in range(args.repeats)]
            median = statistics.median(r[0] for r in runs)
            p90 = statistics.median(r[1] for r in runs)
            print(f"{dialect:<8} {link:<5} {median:>10.3f} {p90:>8.3f} {1e3 / median:>9.0f}")
            medians_s[f"{dialect} over {link}: one state poll"] = median / 1e3
            medians_s[f"{dialect} over {link}: 90th percentile poll"] = p90 / 1e3
    rates = [measure_physics() for _ in range(args.repeats)]
    print(f"simulated chamber: 8 h of ramp and soak read every simulated second: "
          f"{statistics.median(rates):,.0f} simulated s per wall s (median of {args.repeats})")
    path = results.record("chamber_speed", medians_s=medians_s,
                          ratios={"simulated chamber: simulated s per wall s": statistics.median(rates)},
                          parameters={"polls": args.polls, "repeats": args.repeats})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
