"""Benchmark: `bench db history` on a records database of 10,000 results (issue 20, "Must show": under 1 s).

Run: python tests/benchmarks/db_history_speed.py [--results 10000] [--units 100] [--repeats 5] [--db-dir DIR]

Builds (once, cached in DIR, default <system temp>/turntable-bench-db-history) two SQLite
databases of `--results` results of 30 coefficients each, made from one real result file
(the in-memory simulated acquisition + the solver) with the values varied per result:
- "fleet": the results spread over `--units` units (100 calibrations each by default);
- "one unit": every result on one unit (the worst case for one history).
Timed (median of the repeats, after one warm-up): the whole command as a user runs it,
`bench db history SERIAL` (open + migrate check + query + analysis + the printed table,
stdout to /dev/null), and the same with `--coefficient Kg_x D0_x`.
"""

from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import hashlib
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import sqlalchemy as sa

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

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


def timed(argv: list[str], repeats: int) -> float:
    times = []
    with open(os.devnull, "w") as devnull:
        for k in range(repeats + 1):
            start = time.perf_counter()
            with contextlib.redirect_stdout(devnull):
                code = main(argv)
            elapsed = time.perf_counter() - start
            assert code == 0, code
            if k:                       # the first is the warm-up
                times.append(elapsed)
    return statistics.median(times)


def run(args: argparse.Namespace) -> None:
    folder = Path(args.db_dir or Path(tempfile.gettempdir()) / "turntable-bench-db-history")
    folder.mkdir(parents=True, exist_ok=True)
    template_path = folder / "template.result.json"
    if not template_path.exists():
        made = write_result(folder / "tpl", "TPL", dt.datetime(2026, 1, 1), seed=1)
        made.rename(template_path)
    template = json.loads(template_path.read_text())
    print(f"databases in {folder} (built once)")
    for label, units, serial in (("fleet", args.units, "SN-00042"), ("one unit", 1, "SN-00000")):
        db = folder / f"{label.replace(' ', '-')}-{args.results}-{units}.sqlite"
        build(db, template, args.results, units)
        per = args.results // units
        full = timed(["db", "history", "--db", str(db), serial], args.repeats)
        two = timed(["db", "history", "--db", str(db), serial, "--coefficient", "Kg_x", "D0_x"], args.repeats)
        print(f"{label:9}: {args.results} results, {units} unit(s), history of {per} calibrations: "
              f"all 30 coefficients {full * 1e3:.0f} ms, 2 coefficients {two * 1e3:.0f} ms "
              f"(median of {args.repeats}; target < 1000 ms)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--results", type=int, default=10000)
    parser.add_argument("--units", type=int, default=100)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--db-dir", metavar="DIR")
    run(parser.parse_args())
