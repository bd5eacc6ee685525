"""Benchmark: `bench apply` of a long log (issue 33, item 6), to CSV and to MCAP.

Issue 33 measured 35 s (CSV) and 69 s (MCAP) for a one-hour 1 kHz log, with one Python call per sample; its
target is under 10 s.

Run: python benchmarks/apply_speed.py [--minutes 60] [--rate-hz 1000] [--repeats 3] [--formats csv mcap]
                                      [--cache DIR] [--rebuild]

A static log of `--minutes` at `--rate-hz` (the simulated IMU, packed layout; `tests/helpers/static_log.py`) and
a result file (the simulated IMU's true coefficients) are built once into the cache (default <system
temp>/turntable-bench-apply). Each repeat runs `bench apply RESULT LOG --out FILE --quiet` in a fresh process
(what a user waits for: the log read and decoded, the samples compensated and written), the formats
interleaved; prints each time and the medians. The machine is shared: run the one-hour log once
(`--repeats 1`), compare code versions on a shorter one.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
LOG_VERSION = 1          # bump when the log's content changes


def build(cache: Path, minutes: float, rate_hz: float, rebuild: bool) -> tuple[Path, Path]:
    """The cached log and result (built when missing or `rebuild`)."""
    sys.path.insert(0, str(REPO))
    from bench.model.imu import default_sim_imu
    from bench.model.result import CalibrationResult, coefficient_table
    from tests.helpers.static_log import write_static_log

    cache.mkdir(parents=True, exist_ok=True)
    log = cache / f"static-{minutes:g}min-{rate_hz:g}hz-v{LOG_VERSION}.mcap"
    result = cache / "truth.result.json"
    if rebuild or not log.exists():
        t0 = time.perf_counter()
        write_static_log(log, minutes * 60.0, rate_hz)
        print(f"built {log} in {time.perf_counter() - t0:.1f} s")
    if rebuild or not result.exists():
        values = default_sim_imu().to_canonical()
        CalibrationResult(coefficient_table(values, {n: 1e-6 for n in values}), run={"run_id": "truth"}).save(result)
    return log, result


def timed_apply(result: Path, log: Path, out: Path) -> float:
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "bench.cli", "apply", str(result), str(log), "--out", str(out), "--quiet"],
                   cwd=REPO, check=True)
    seconds = time.perf_counter() - t0
    out.unlink()
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--formats", nargs="+", choices=("csv", "mcap"), default=["csv", "mcap"])
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "turntable-bench-apply")
    parser.add_argument("--rebuild", action="store_true")
    args = parser.parse_args()
    log, result = build(args.cache, args.minutes, args.rate_hz, args.rebuild)
    samples = int(round(args.minutes * 60.0 * args.rate_hz))
    times: dict[str, list[float]] = {fmt: [] for fmt in args.formats}
    for repeat in range(args.repeats):
        for fmt in args.formats:
            seconds = timed_apply(result, log, args.cache / f"applied.{fmt}")
            times[fmt].append(seconds)
            print(f"repeat {repeat + 1}: {fmt} {seconds:.2f} s ({seconds / samples * 1e6:.2f} us a sample)", flush=True)
    for fmt, values in times.items():
        median = statistics.median(values)
        print(f"bench apply to {fmt}: median {median:.2f} s over {len(values)} run(s) "
              f"({min(values):.2f}-{max(values):.2f}); {samples:,} samples ({args.minutes:g} min at "
              f"{args.rate_hz:g} Hz), {median / samples * 1e6:.2f} us a sample")


if __name__ == "__main__":
    main()
