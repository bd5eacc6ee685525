"""Benchmark: `bench apply` of a long log (issue 33, item 6), to CSV and to MCAP.

Issue 33 measured 35 s (CSV) and 69 s (MCAP) for a one-hour 1 kHz log, with one Python call per sample; its
target is under 10 s.

Run: python benchmarks/apply_speed.py [--minutes 60] [--rate-hz 1000] [--repeats 3] [--formats csv mcap]
                                      [--against DIR] [--cache DIR] [--rebuild]

A static log of `--minutes` at `--rate-hz` (the simulated IMU, packed layout; `tests/helpers/static_log.py`) and
a result file (the simulated IMU's true coefficients) are built once into the cache (default <system
temp>/turntable-bench-apply). Each repeat runs `bench apply RESULT LOG --out FILE --quiet` in a fresh process
(what a user waits for: the log read and decoded, the samples compensated and written), the formats (and, with
`--against DIR`, this checkout and another one) alternated; prints each run's wall and CPU time (the child's
user + system) and the load, then the medians, and writes them to benchmarks/results/apply_speed.json. With
`--against`, the two checkouts' outputs are compared: the same bytes, or else value for value (every number of
every CSV row and MCAP message read back as floats). The machine is shared: prefix `nice -n 19` and read the CPU times.
"""

from __future__ import annotations

import argparse
import csv
import filecmp
import json
import os
import resource
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


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def timed_apply(checkout: Path, result: Path, log: Path, out: Path) -> tuple[float, float]:
    """(wall s, CPU s) of one `bench apply` of `checkout`'s code in a fresh process."""
    cpu0, t0 = _children_cpu_s(), time.perf_counter()
    subprocess.run([sys.executable, "-m", "bench.cli", "apply", str(result), str(log), "--out", str(out), "--quiet"],
                   cwd=checkout, check=True)
    return time.perf_counter() - t0, _children_cpu_s() - cpu0


def _values(path: Path) -> list:
    """Every number of an output, as floats (JSON null as NaN), in file order: rows or (topic, log time, body)."""
    if path.suffix == ".csv":
        with open(path, encoding="utf-8", newline="") as f:
            rows = csv.reader(f)
            return [next(rows)] + [[float(x) for x in row] for row in rows]
    from mcap.reader import make_reader

    def floats(value):
        if isinstance(value, list):
            return [floats(x) for x in value]
        return float("nan") if value is None else value if isinstance(value, str) else float(value)

    with open(path, "rb") as f:
        return [(channel.topic, message.log_time, {k: floats(v) for k, v in json.loads(message.data).items()})
                for _s, channel, message in make_reader(f).iter_messages(log_time_order=False)]


def same_values(a: Path, b: Path) -> bool:
    """True when the two outputs hold the same numbers in the same order (NaN equal to NaN): at once when the files
    are the same bytes (reading a one-hour MCAP's 7.2 million messages back in Python takes many minutes)."""
    if filecmp.cmp(a, b, shallow=False):
        return True
    return json.dumps(_values(a)) == json.dumps(_values(b))


def main() -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import results

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--formats", nargs="+", choices=("csv", "mcap"), default=["csv", "mcap"])
    parser.add_argument("--against", metavar="DIR", type=Path, help="another checkout to run alternately")
    parser.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "turntable-bench-apply")
    parser.add_argument("--rebuild", action="store_true")
    args = parser.parse_args()
    log, result = build(args.cache, args.minutes, args.rate_hz, args.rebuild)
    samples = int(round(args.minutes * 60.0 * args.rate_hz))
    checkouts = {"this": REPO} if args.against is None else {"base": args.against.resolve(), "this": REPO}
    times: dict[tuple[str, str], list[tuple[float, float]]] = {}
    same: dict[str, bool] = {}
    for repeat in range(args.repeats):
        for fmt in args.formats:
            for name, checkout in checkouts.items():
                out = args.cache / f"applied-{name}.{fmt}"
                wall, cpu = timed_apply(checkout, result, log, out)
                times.setdefault((name, fmt), []).append((wall, cpu))
                load = os.getloadavg()
                print(f"repeat {repeat + 1}: {name} {fmt}: {wall:.2f} s wall, {cpu:.2f} s CPU "
                      f"({cpu / samples * 1e6:.2f} us CPU a sample); load {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}",
                      flush=True)
            if args.against is not None and fmt not in same:
                same[fmt] = same_values(args.cache / f"applied-base.{fmt}", args.cache / f"applied-this.{fmt}")
                print(f"{fmt}: the same values as the base's output: {same[fmt]}", flush=True)
            for name in checkouts:
                (args.cache / f"applied-{name}.{fmt}").unlink()
    medians, ratios = results.wall_cpu_medians(times, lambda fmt: f"bench apply to {fmt}", args.against is not None)
    for (name, fmt), values in times.items():
        wall, cpu = medians[f"{name}: bench apply to {fmt}, wall"], medians[f"{name}: bench apply to {fmt}, CPU"]
        print(f"{name}: bench apply to {fmt}: median {wall:.2f} s wall, {cpu:.2f} s CPU over {len(values)} run(s); "
              f"{samples:,} samples ({args.minutes:g} min at {args.rate_hz:g} Hz), target < 10 s: "
              f"{'met' if wall < 10 else 'MISSED'} (wall), {'met' if cpu < 10 else 'MISSED'} (CPU)")
    path = results.record("apply_speed", medians_s=medians, ratios=ratios,
                          parameters={"minutes": args.minutes, "rate_hz": args.rate_hz, "repeats": args.repeats,
                                      "against": str(args.against or "")},
                          note=("the base's and this checkout's outputs hold the same values: "
                                + ", ".join(f"{fmt} {ok}" for fmt, ok in same.items())) if same else "")
    print(f"figures written to {path}")


if __name__ == "__main__":
    main()
