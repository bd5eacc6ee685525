"""Benchmark: `bench db history` on a records database of 10,000 results (issue 20, "Must show": under 1 s).

Run: python benchmarks/db_history_speed.py [--results 10000] [--units 100] [--repeats 5] [--db-dir DIR]
         [--baseline TREE]

Builds (once, cached in DIR, default <system temp>/turntable-bench-db-history) two SQLite
databases of `--results` results of 30 coefficients each, made from one real result file
(the in-memory simulated acquisition + the solver) with the values varied per result:
- "fleet": the results spread over `--units` units (100 calibrations each by default);
- "one unit": every result on one unit (the worst case for one history).
Timed (median of the repeats, after one warm-up; wall and CPU time of the process): the whole
command as a user runs it, `bench db history SERIAL` (open + migrate check + query + analysis
+ the printed table, stdout to /dev/null), and the same with `--coefficient Kg_x D0_x`.
With `--baseline TREE` (another checkout, e.g. `git worktree add /tmp/before COMMIT`) each
case is timed in this tree and in TREE alternately, each in a fresh process (imports not
timed), side by side, and the printed tables are checked to be identical.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import hashlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import sqlalchemy as sa
from results import record

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench.cli.main import main  # noqa: E402
from bench.records import schema  # noqa: E402
from bench.records.store import open_records  # noqa: E402
from tests.helpers.records import write_result  # noqa: E402


def build(db: Path, template: dict, results: int, units: int) -> None:
    """`results` results over `units` units, bulk-inserted with SQLAlchemy Core (what import would write)."""
    if db.exists():
        return
    tmp = db.with_suffix(".building")
    tmp.unlink(missing_ok=True)
    with open_records(str(tmp)) as records:
        rng = np.random.default_rng(1)
        names = list(template["coefficients"])
        values = np.array([template["coefficients"][n]["value"] for n in names])
        sigmas = np.array([template["coefficients"][n]["sigma"] for n in names])
        t0 = dt.datetime(2020, 1, 1)
        per_unit = results // units
        with records.engine.begin() as conn:
            conn.execute(sa.insert(schema.units), [{"id": u + 1, "model": "sim FOG", "serial": f"SN-{u:05d}"}
                                                   for u in range(units)])
            runs, rows, coefs = [], [], []
            for k in range(results):
                unit = k // per_unit if k // per_unit < units else units - 1
                when = t0 + dt.timedelta(hours=6 * (k % per_unit) + unit)
                runs.append({"id": k + 1, "run_id": f"run-{k:06d}", "unit_id": unit + 1, "kind": "calibration",
                             "mode": "simulator", "operator": "bench", "table_url": "", "plan": "optimal",
                             "software_version": "0.1.0", "started_utc": when, "outcome": "done"})
                rows.append({"id": k + 1, "run_pk": k + 1, "sha256": hashlib.sha256(str(k).encode()).hexdigest(),
                             "software_version": "0.1.0", "solved_utc": when, "imported_utc": when,
                             "verdict": "pass"})
                v = values + rng.normal(0.0, 1.0, len(names)) * sigmas
                coefs += [{"result_id": k + 1, "name": n, "value": float(x), "sigma": float(s), "unit": "u"}
                          for n, x, s in zip(names, v, sigmas)]
            conn.execute(sa.insert(schema.runs), runs)
            conn.execute(sa.insert(schema.results), rows)
            conn.execute(sa.insert(schema.coefficients), coefs)
    tmp.rename(db)


def timed(argv: list[str], repeats: int) -> tuple[float, float]:
    """Median (wall s, CPU s) of `bench` run in this process with `argv`, after one warm-up."""
    walls, cpus = [], []
    with open(os.devnull, "w") as devnull:
        for k in range(repeats + 1):
            start, cpu = time.perf_counter(), time.process_time()
            with contextlib.redirect_stdout(devnull):
                code = main(argv)
            elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
            assert code == 0, code
            if k:                       # the first is the warm-up
                walls.append(elapsed)
                cpus.append(cpu)
    return statistics.median(walls), statistics.median(cpus)


#: `timed` in a child process on another tree's `bench` (self-contained: the other tree's benchmark may differ)
_CHILD = """
import contextlib, json, os, statistics, sys, time
from bench.cli.main import main
argv, repeats = json.loads(sys.argv[1]), int(sys.argv[2])
walls, cpus = [], []
with open(os.devnull, "w") as devnull:
    for k in range(repeats + 1):
        start, cpu = time.perf_counter(), time.process_time()
        with contextlib.redirect_stdout(devnull):
            assert main(argv) == 0
        if k:
            walls.append(time.perf_counter() - start)
            cpus.append(time.process_time() - cpu)
print(json.dumps([statistics.median(walls), statistics.median(cpus)]))
"""


def timed_in(tree: Path, argv: list[str], repeats: int) -> tuple[float, float]:
    """`timed` in a fresh process on the code of `tree` (PYTHONPATH=tree)."""
    done = subprocess.run([sys.executable, "-c", _CHILD, json.dumps(argv), str(repeats)], capture_output=True,
                          text=True, check=True, cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)})
    wall, cpu = json.loads(done.stdout.strip().splitlines()[-1])
    return wall, cpu


def printed(tree: Path, argv: list[str]) -> str:
    return subprocess.run([sys.executable, "-m", "bench.cli", *argv], capture_output=True, text=True, check=True,
                          cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)}).stdout


def run(args: argparse.Namespace) -> None:
    folder = Path(args.db_dir or Path(tempfile.gettempdir()) / "turntable-bench-db-history")
    folder.mkdir(parents=True, exist_ok=True)
    template_path = folder / "template.result.json"
    if not template_path.exists():
        made = write_result(folder / "tpl", "TPL", dt.datetime(2026, 1, 1), seed=1)
        made.rename(template_path)
    template = json.loads(template_path.read_text())
    print(f"databases in {folder} (built once)")
    medians_s: dict[str, float] = {}
    ratios: dict[str, float] = {}
    for label, units, serial in (("fleet", args.units, "SN-00042"), ("one unit", 1, "SN-00000")):
        db = folder / f"{label.replace(' ', '-')}-{args.results}-{units}.sqlite"
        build(db, template, args.results, units)
        per = args.results // units
        cases = (("all 30 coefficients", ["db", "history", "--db", str(db), serial]),
                 ("2 coefficients", ["db", "history", "--db", str(db), serial, "--coefficient", "Kg_x", "D0_x"]))
        for what, argv in cases:
            load = os.getloadavg()[0]
            if args.baseline is None:
                wall, cpu = timed(argv, args.repeats)
                print(f"{label:9}: {args.results} results, {units} unit(s), history of {per} calibrations, {what}: "
                      f"{wall * 1e3:.0f} ms wall, {cpu * 1e3:.0f} ms CPU (median of {args.repeats}; load {load:.1f}; "
                      f"target < 1000 ms)")
                medians_s[f"{label}, history of {per} calibrations, {what}: wall"] = wall
                medians_s[f"{label}, history of {per} calibrations, {what}: CPU"] = cpu
                continue
            here = Path(__file__).resolve().parents[1]
            base, new = [], []
            for _ in range(args.rounds):        # alternately, so that a change of load hits both alike
                base.append(timed_in(Path(args.baseline), argv, args.repeats))
                new.append(timed_in(here, argv, args.repeats))
            (bw, bc), (nw, nc) = [tuple(statistics.median(x[i] for x in runs) for i in (0, 1)) for runs in (base, new)]
            same = printed(Path(args.baseline), argv) == printed(here, argv)
            print(f"{label:9}: history of {per} calibrations, {what}: baseline {bw * 1e3:.0f} ms wall / {bc * 1e3:.0f} "
                  f"ms CPU, this tree {nw * 1e3:.0f} ms wall / {nc * 1e3:.0f} ms CPU ({bc / nc:.1f}x less CPU; "
                  f"medians of {args.rounds} alternating processes x {args.repeats}; load {load:.1f} at the start; "
                  f"identical output: {same})")
            medians_s[f"{label}, history of {per} calibrations, {what}: CPU, this tree"] = nc
            medians_s[f"{label}, history of {per} calibrations, {what}: CPU, baseline"] = bc
            ratios[f"{label}, {what}: baseline CPU / this tree's"] = bc / nc
    path = record("db_history_speed", medians_s=medians_s, ratios=ratios, parameters={
        "results": args.results, "units": args.units, "repeats": args.repeats, "baseline": args.baseline or ""})
    print(f"figures written to {path}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=int, default=10000)
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--db-dir", metavar="DIR")
    parser.add_argument("--baseline", metavar="TREE", help="also time this checkout, alternately, side by side")
    parser.add_argument("--rounds", type=int, default=3, help="with --baseline: alternating processes per tree")
    run(parser.parse_args())
