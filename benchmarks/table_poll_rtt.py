"""Benchmark: turntable state-poll round trip to the simulator, per dialect, over TCP loopback and a pty.

Run: python benchmarks/table_poll_rtt.py [--polls 2000] [--repeats 5]
For each dialect (scpi, mn, modbus, acutrol) it serves the simulated table in that dialect on
127.0.0.1 (Modbus TCP for modbus) and on a pty (Modbus RTU for modbus, 115200 baud
nominal), connects the real driver through the real transport, and times
`read_state()` (one full state of the three axes); everything measured in one run,
side by side. Prints the median and 90th percentile per poll in ms (median over
repeats) and the polls per second the median implies. The Modbus watchdog is off so
that every request is a poll.
"""

from __future__ import annotations

import argparse
import statistics
import sys
from pathlib import Path

import results

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.sim.controller import SimController  # noqa: E402
from bench.sim.serve import LineServer  # noqa: E402
from drivers.turntable import open_turntable  # noqa: E402
from tests.helpers.timing import poll_ms  # noqa: E402


def _serve(dialect: str, controller: SimController, link: str):
    """(url, driver options, closer) of a server of the simulated table in `dialect` over `link` (tcp|pty)."""
    if dialect == "modbus":
        from bench.sim.modbus_server import ModbusSimServer
        from drivers.turntable.modbus_map import RegisterMap

        register_map = RegisterMap.default().with_changes(watchdog_s=0)
        server = ModbusSimServer(controller, register_map)
        if link == "pty":
            url = f"modbus+rtu://{server.start_rtu_pty()}?baud=115200"
        else:
            url = "modbus+tcp://{}:{}".format(*server.start_tcp("127.0.0.1", 0))
        return url, {"register_map": register_map}, server.close
    from bench.sim.acutrol_server import AcutrolSimHandler
    from bench.sim.mn_server import MnSimHandler
    from bench.sim.scpi_server import ScpiSimHandler

    handlers = {"acutrol": AcutrolSimHandler, "scpi": ScpiSimHandler, "mn": MnSimHandler}
    line_server = LineServer(handlers[dialect](controller))
    url = line_server.open_pty() if link == "pty" else "tcp://{}:{}".format(*line_server.listen_tcp("127.0.0.1", 0))
    return url, {}, line_server.close


def measure(dialect: str, polls: int, link: str = "tcp") -> tuple[float, float]:
    """(median ms, p90 ms) of `polls` state reads."""
    controller = SimController()
    url, options, close = _serve(dialect, controller, link)
    try:
        with open_turntable(url, dialect, timeout_s=1.0, **options) as table:
            table.enable()
            return poll_ms(table.read_state, polls)
    finally:
        close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--polls", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--dialects", default="scpi,mn,modbus,acutrol")
    args = parser.parse_args()
    print(f"state poll round trip, {args.polls} polls x {args.repeats} repeats")
    print(f"{'dialect':<8} {'link':<5} {'median ms':>10} {'p90 ms':>8} {'polls/s':>9}")
    medians_s: dict[str, float] = {}
    for dialect in args.dialects.split(","):
        for link in ("tcp", "pty"):
            runs = [measure(dialect, args.polls, link) for _ in range(args.repeats)]
            median = statistics.median(r[0] for r in runs)
            p90 = statistics.median(r[1] for r in runs)
            print(f"{dialect:<8} {link:<5} {median:>10.3f} {p90:>8.3f} {1e3 / median:>9.0f}")
            medians_s[f"{dialect} over {link}: one state poll"] = median / 1e3
            medians_s[f"{dialect} over {link}: 90th percentile poll"] = p90 / 1e3
    path = results.record("table_poll_rtt", medians_s=medians_s, parameters={
        "polls": args.polls, "repeats": args.repeats, "dialects": args.dialects})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
