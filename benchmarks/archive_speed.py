"""Benchmark and must-show check: re-solving an archive of 50 simulated logs on Dask (issue 20).

Run: python benchmarks/archive_speed.py [--logs 50] [--units 5] [--repeats 1] [--dir DIR]
         [--rate-hz 50] [--dwell-s 2] [--distinct N]

Builds once (cached in DIR, default <system temp>/turntable-bench-archive) an archive of
`--logs` real run logs recorded with `bench run --config` on the simulator (`--units` IMUs
by serial, noise on, each run its own seed; by default 2 s dwells at 50 Hz), plus damaged logs
(two more runs, one cut at 60 % of its bytes, one with 4 KiB of garbage in its middle) and a
file that is not MCAP. Logs that take seconds to solve (a real archive's 1 kHz runs, e.g.
`--rate-hz 1000 --dwell-s 30`) take a minute each to record: `--distinct N` records N runs
and fills the archive with hard links to them in folders of their own (every log is still
read and solved on its own; the results are identical per source run).
Then, side by side in one run (`--scaling-only`: step 1 alone, the four commands' results
checked against each other; with `--repeats` every other repeat runs them in reverse order):
1. `bench solve --archive DIR --scheduler loop` (the plain loop in one process),
   `--scheduler local --workers 1` and `--workers 2`, each into a fresh --out, without
   the database, and the plain loop once more with the reader's own threads (as `bench
   solve LOG` reads; an archive task reads without them, one core's work); wall time of
   the whole command (cluster start-up included), and without the cluster's start-up and
   close (timed alone right after: a cluster started for no task);
2. equivalence: every result file of the Dask run equals (but its solved_utc) the one `bench solve LOG
   --no-html` writes for that log one by one, and the damaged logs are reported;
3. the database: the archive solved with --db into a fresh SQLite file holds every unit's
   history (`bench db history` of each serial lists its runs).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from results import record  # noqa: E402

import bench.jobs.archive as archive_module  # noqa: E402
from bench.cli.main import main  # noqa: E402
from bench.jobs.archive import solve_archive  # noqa: E402
from tests.helpers.run import config_text, results_below  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


def _record(folder: Path, serial: str, seed: int, dwell_s: float = 2.0, rate_hz: float = 50.0) -> None:
    if any(folder.glob("*.mcap")):
        return
    folder.mkdir(parents=True, exist_ok=True)
    config = folder / "bench.toml"
    config.write_text(config_text(noise="true", seed=seed, dwell_s=dwell_s, rate_hz=rate_hz, black_box_arcsec=10.0)
                      .replace('serial = "T-0001"', f'serial = "{serial}"'), encoding="utf-8")
    subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(config), "--out", str(folder / "run"),
                    "--quiet", "--no-db"], check=True, cwd=REPO, capture_output=True,
                   env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"})
    log = next((folder / "run").glob("*.mcap"))
    shutil.move(str(log), folder / log.name)
    shutil.rmtree(folder / "run")


def build(root: Path, logs: int, units: int, dwell_s: float = 2.0, rate_hz: float = 50.0,
          distinct: int | None = None) -> None:
    distinct = min(distinct or logs, logs)
    jobs = [(root / f"unit-{k % units}" / f"run-{k:03d}", f"SN-{k % units:03d}", 100 + k, dwell_s, rate_hz)
            for k in range(distinct)]
    with ThreadPoolExecutor(2) as pool:
        list(pool.map(lambda j: _record(*j), jobs))
    for k in range(distinct, logs):     # hard links to the recorded runs, each in a folder of its own
        source_folder = jobs[k % distinct][0]
        folder = source_folder.parent / f"run-{k:03d}"
        if not any(folder.glob("*.mcap")):
            folder.mkdir(parents=True, exist_ok=True)
            source = next(source_folder.glob("*.mcap"))
            (folder / source.name).hardlink_to(source)
    damaged = root / "damaged"
    if not damaged.exists():
        # two runs of their own (a damaged log is the only copy of its run), then damaged in place
        source = root.parent / "damaged-source"
        for k, name in enumerate(("cut", "garbage")):
            _record(source / name, f"SN-D{k}", 900 + k)
        damaged.mkdir()
        cut = next((source / "cut").glob("*.mcap"))
        data = cut.read_bytes()
        (damaged / cut.name).write_bytes(data[: int(len(data) * 0.6)])
        garbage = next((source / "garbage").glob("*.mcap"))
        data = garbage.read_bytes()
        middle = len(data) // 2
        (damaged / garbage.name).write_bytes(data[:middle] + b"\xff" * 4096 + data[middle + 4096:])
        (damaged / "not-mcap.mcap").write_bytes(b"this is not a log\n" * 100)


THREADED_LOOP = "loop, reader threads"


@contextlib.contextmanager
def threaded_reader():
    """The archive's tasks read as `bench solve LOG` does, with the reader's own threads (an archive task reads
    without: `bench.jobs.archive.solve_log`): what a shell loop of `bench solve` would take."""
    original = archive_module.reader_threads_limited
    archive_module.reader_threads_limited = lambda threads: contextlib.nullcontext()
    try:
        yield
    finally:
        archive_module.reader_threads_limited = original


def cli(argv: list[str]) -> tuple[int, str, str, float]:
    out, err = io.StringIO(), io.StringIO()
    start = time.perf_counter()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(argv)
    return rc, out.getvalue(), err.getvalue(), time.perf_counter() - start


def run(args: argparse.Namespace) -> None:
    root = Path(args.dir or Path(tempfile.gettempdir()) / "turntable-bench-archive")
    archive = root / "archive"
    t = time.perf_counter()
    build(archive, args.logs, args.units, args.dwell_s, args.rate_hz, args.distinct)
    size_mb = sum(p.stat().st_size for p in archive.rglob("*.mcap")) / 1e6
    print(f"archive {archive}: {args.logs} logs of {args.units} IMUs ({args.distinct or args.logs} distinct runs, "
          f"{args.dwell_s:g} s dwells at {args.rate_hz:g} Hz) + 3 damaged, {size_mb:.0f} MB (built in "
          f"{time.perf_counter() - t:.0f} s, cached)")
    work = Path(tempfile.mkdtemp(prefix="archive-bench-"))
    try:
        # one by one, as a user would: bench solve LOG --no-html, each into its own folder
        one = work / "one-by-one"
        failed_one = []
        for log in ([] if args.scaling_only else sorted(archive.rglob("*.mcap"))):
            out = one / log.parent.relative_to(archive)
            rc, _, err, _ = cli(["solve", str(log), "--out", str(out), "--no-html", "--no-db", "--quiet"])
            if rc not in (0, 4):
                failed_one.append(log.name)
        reference = results_below(one) if not args.scaling_only else None
        timings: dict[str, list[float]] = {}
        commands = (("loop", ["--scheduler", "loop"]),
                    ("dask 1 worker", ["--scheduler", "local", "--workers", "1"]),
                    ("dask 2 workers", ["--scheduler", "local", "--workers", "2"]),
                    (THREADED_LOOP, ["--scheduler", "loop"]))
        for repeat in range(args.repeats):
            # every other repeat in reverse order: a load that changes during the run hits all four alike
            for label, extra in (commands if repeat % 2 == 0 else commands[::-1]):
                out = work / f"{label.replace(' ', '-').replace(',', '')}-{repeat}"
                with (threaded_reader() if label == THREADED_LOOP else contextlib.nullcontext()):
                    rc, stdout, stderr, wall = cli(["solve", "--archive", str(archive), "--out", str(out),
                                                    "--no-db", "--quiet", *extra])
                timings.setdefault(label, []).append(wall)
                got = results_below(out)
                if reference is None:       # --scaling-only: the first command's results are the reference
                    reference = got
                same = got == reference
                reported = sorted(line.split(" FAILED ")[1].split(":")[0].rsplit("/", 1)[-1]
                                  for line in stderr.splitlines() if " FAILED " in line)
                against = "the first command" if args.scaling_only else "one-by-one"
                print(f"{label:15} {wall:6.1f} s  (load {os.getloadavg()[0]:.1f})  exit {rc}  {len(got)} results, "
                      f"identical to {against}: {same}; failed: {', '.join(reported)}")
            for label, n in (("dask 1 worker", 1), ("dask 2 workers", 2)):
                start = time.perf_counter()
                solve_archive([], scheduler="local", workers=n)       # the cluster started and closed, no task
                timings.setdefault(f"{label} start-up", []).append(time.perf_counter() - start)
        for k in range(args.repeats):       # each repeat's three commands ran back to back: their ratios
            t = {label: v[k] for label, v in timings.items()}
            print(f"repeat {k + 1}: 2 workers vs 1 {t['dask 1 worker'] / t['dask 2 workers']:.2f}x, Dask 1 worker vs "
                  f"the loop {100 * (t['dask 1 worker'] / t['loop'] - 1):+.1f} %")
        med = {k: statistics.median(v) for k, v in timings.items()}
        for label in ("dask 1 worker", "dask 2 workers"):
            med[f"{label} solving"] = med[label] - med[f"{label} start-up"]
            print(f"{label}: cluster start-up and close {med[f'{label} start-up']:.1f} s, "
                  f"the rest {med[f'{label} solving']:.1f} s")
        print(f"2 workers vs the plain loop with the reader's threads (as `bench solve LOG` reads): "
              f"{med[THREADED_LOOP] / med['dask 2 workers']:.2f}x; the loop without them vs with: "
              f"{100 * (med['loop'] / med[THREADED_LOOP] - 1):+.1f} %")
        print(f"one-by-one bench solve failed on: {', '.join(sorted(failed_one))}")
        print(f"speed-up 2 workers vs 1: {med['dask 1 worker'] / med['dask 2 workers']:.2f}x whole command, "
              f"{med['dask 1 worker solving'] / med['dask 2 workers solving']:.2f}x without the cluster start-up "
              f"(target >= 1.7); Dask 1 worker vs the plain loop: "
              f"{100 * (med['dask 1 worker'] / med['loop'] - 1):+.1f} % whole command, "
              f"{100 * (med['dask 1 worker solving'] / med['loop'] - 1):+.1f} % without the start-up "
              f"(target < 10 %)")
        path = record("archive_speed", medians_s={f"bench solve --archive of {args.logs} logs, {label}": seconds
                                                  for label, seconds in med.items()},
                      ratios={"2 workers vs 1, whole command": med["dask 1 worker"] / med["dask 2 workers"],
                              "2 workers vs 1, without the cluster start-up":
                                  med["dask 1 worker solving"] / med["dask 2 workers solving"],
                              "Dask 1 worker / the plain loop": med["dask 1 worker"] / med["loop"]},
                      parameters={"logs": args.logs, "repeats": args.repeats, "rate_hz": args.rate_hz,
                                  "dwell_s": args.dwell_s, "distinct": args.distinct})
        print(f"figures written to {path}")
        if args.scaling_only:
            return
        db = work / "records.sqlite"
        rc, stdout, stderr, wall = cli(["solve", "--archive", str(archive), "--db", str(db), "--quiet",
                                        "--out", str(work / "with-db"), "--workers", "2"])
        rc2, stdout2, _, _ = cli(["solve", "--archive", str(archive), "--db", str(db), "--quiet",
                                  "--out", str(work / "with-db"), "--workers", "2"])
        print(f"with the database: {wall:.1f} s; again: {stdout2.strip().splitlines()[-1]}")
        for unit in range(args.units):
            rc, stdout, _, _ = cli(["db", "history", "--db", str(db), f"SN-{unit:03d}", "--coefficient", "Kg_x"])
            print(f"  {stdout.splitlines()[0]}")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--logs", type=int, default=50)
    parser.add_argument("--units", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--dir", metavar="DIR")
    parser.add_argument("--rate-hz", type=float, default=50.0, help="IMU sample rate of the recorded runs")
    parser.add_argument("--dwell-s", type=float, default=2.0, help="dwell time of the recorded runs")
    parser.add_argument("--scaling-only", action="store_true",
                        help="only the timed commands (their results checked against each other), no one-by-one "
                             "reference and no database pass")
    parser.add_argument("--distinct", type=int, help="record this many runs, hard-link the rest (default: all)")
    run(parser.parse_args())
