"""Benchmark: several IMUs against `bench sim rig` in wall-clock time, over SLCAN and socketcand (issue 31).

Issue 31 asks that four units on two faces and two buses each recover their truth within U against `bench sim rig
--imus 4` in wall-clock time, over SLCAN and socketcand, and that the run take at most 1.3x a single unit's (the
table's time is the cost).

Run: python benchmarks/several_imus_rig.py [--units 4] [--buses 2] [--transports slcan,socketcand] [--dwell-s 1]
[--rate-hz 200] [--note TEXT]

For each transport, starts `bench sim rig --imus 1` and `bench sim rig --imus N --buses B` (SCPI over TCP; the units
over one SLCAN adapter (pty) or one socketcand per bus, units sharing a bus sharing it; 200 Hz, classic layout, noise
on) and runs `bench run --config <the written configuration>` against each with a short plan (traditional-12 +
traditional-3s6r, `--dwell-s` dwells, fast moves and turns) as two processes. Reports per unit its worst |error| / U
against the rig's truth (each unit's own, as `bench run --sim` draws it) and its lost samples; per run the wall time
of `bench run` (the plan plus the IMU checks before it and the solves after it), the run's table time (first to last
table state of its log), their ratios N units / 1 unit, and the CPU `bench run` used.
One run of each (the "medians" are single runs).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import results

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bench.config.load import load_config  # noqa: E402
from bench.log.reader import read_log  # noqa: E402
from bench.model.result import coefficient_table  # noqa: E402
from bench.sim.units import unit_truth  # noqa: E402
from tests.helpers.sim_process import read_until  # noqa: E402
from tests.protocol.test_sim_rig import RIG_CONFIG, _start_rig, _with_plan  # noqa: E402

LISTEN = {"slcan": "slcan", "socketcand": "socketcand://127.0.0.1:0"}


def short_plan(dwell_s: float) -> str:
    return (f'[plan]\npositions = "traditional-12"\nrotations = "traditional-3s6r"\ndwell_s = {dwell_s}\n'
            "settle_s = 0.2\nrest_s = 0.2\nmove_rate_dps = 500.0\nmove_accel_dps2 = 2000.0\nturn_rate_dps = 500.0\n"
            "turn_accel_dps2 = 2000.0\n\n")


def one_run(transport: str, units: int, buses: int, dwell_s: float, rate_hz: float) -> dict:
    """`bench run` against a rig of `units` units on `buses` buses: wall time, CPU, and per unit (serial ->)
    worst |error| / U and lost samples."""
    work = Path(tempfile.mkdtemp(prefix="several-imus-rig-"))
    rig_config = work / "rig.toml"
    rig_config.write_text(RIG_CONFIG.format(dialect="scpi").replace("rate_hz = 100.0", f"rate_hz = {rate_hz}"))
    written = work / "bench.toml"
    rig = _start_rig("--config", str(rig_config), "--table-listen", "tcp://127.0.0.1:0", "--imu-listen",
                     LISTEN[transport], "--imus", str(units), "--buses", str(buses), "--write-config", str(written))
    try:
        read_until(rig, "Ctrl-C stops")
        written.write_text(_with_plan(written.read_text(), short_plan(dwell_s)))
        out = work / "runs"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.monotonic()
        run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out", str(out),
                              "--quiet", "--no-db"], cwd=REPO, capture_output=True, text=True, timeout=900)
        wall_s = time.monotonic() - t0
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu_s = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        config = load_config(written)
        logs = list(out.glob("*.mcap"))
        table_s = float("nan")
        if len(logs) == 1:     # the run's duration: the table's time, first to last table state of the log
            states = read_log(logs[0]).read_table_states().time_s
            table_s = float(states[-1] - states[0])
        per_unit = {}
        for k, unit in enumerate(config.units or (config.imu,)):
            found = list(out.glob(f"*.{unit.identity.serial}.result.json" if config.several else "*.result.json"))
            if len(found) != 1:
                continue
            result = json.loads(found[0].read_text())
            truth = {name: entry.to_json()["value"] for name, entry in coefficient_table(
                unit_truth(config.sim.imu, k, config.sim.seed).to_canonical()).items()}
            link = result["run"]["imu_link"]
            worst = max(abs(e["value"] - truth[n]) / e["expanded"] for n, e in result["coefficients"].items())
            per_unit[unit.identity.serial] = {
                "worst_error_over_u": worst, "lost_samples": link["incomplete_samples"] + link["counter_gaps"],
                "samples": link["samples"]}
        return {"wall_s": wall_s, "table_s": table_s, "cpu_s": cpu_s, "exit": run.returncode,
                "stderr": run.stderr.strip()[-300:], "units": per_unit, "folder": str(work)}
    finally:
        rig.terminate()
        try:
            rig.wait(timeout=10)
        except subprocess.TimeoutExpired:
            rig.kill()


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--units", type=int, default=4)
    ap.add_argument("--buses", type=int, default=2)
    ap.add_argument("--transports", default="slcan,socketcand")
    ap.add_argument("--dwell-s", type=float, default=1.0)
    ap.add_argument("--rate-hz", type=float, default=200.0)
    ap.add_argument("--note", default="", help="a line for docs/benchmarks.md (what the figures say, the machine)")
    args = ap.parse_args()
    transports = args.transports.split(",")
    print(f"{args.units} units on {args.buses} buses against 1 unit, {args.rate_hz:g} Hz, dwells {args.dwell_s:g} s; "
          f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}", flush=True)
    medians_s: dict[str, float] = {}
    ratios: dict[str, float] = {}
    ok = True
    for transport in transports:
        single = one_run(transport, 1, 1, args.dwell_s, args.rate_hz)
        several = one_run(transport, args.units, args.buses, args.dwell_s, args.rate_hz)
        for name, r in (("1 unit", single), (f"{args.units} units", several)):
            print(f"{transport}, {name}: bench run exit {r['exit']}, {r['wall_s']:.1f} s wall (the run's table time "
                  f"{r['table_s']:.1f} s), CPU {r['cpu_s']:.1f} s"
                  + (f" ({r['stderr']})" if r["exit"] else ""), flush=True)
            for serial, u in r["units"].items():
                print(f"  {serial}: worst |error| / U {u['worst_error_over_u']:.2f}, {u['samples']} samples, "
                      f"lost {u['lost_samples']}", flush=True)
            medians_s[f"{transport}, {name}: bench run wall time"] = r["wall_s"]
            medians_s[f"{transport}, {name}: the run's table time (log)"] = r["table_s"]
            medians_s[f"{transport}, {name}: bench run CPU"] = r["cpu_s"]
            ok = ok and r["exit"] == 0 and len(r["units"]) == (1 if r is single else args.units)
        wall_ratio = several["wall_s"] / single["wall_s"]
        ratios[f"{transport}: wall time, {args.units} units / 1 unit"] = wall_ratio
        ratios[f"{transport}: table time, {args.units} units / 1 unit"] = several["table_s"] / single["table_s"]
        ratios[f"{transport}: CPU of bench run, {args.units} units / 1 unit"] = several["cpu_s"] / single["cpu_s"]
        for serial, u in several["units"].items():
            ratios[f"{transport}, {serial}: worst |error| / U"] = u["worst_error_over_u"]
            ratios[f"{transport}, {serial}: lost samples"] = float(u["lost_samples"])
        print(f"{transport}: wall time {args.units} units / 1 unit = {wall_ratio:.3f} (issue 31: at most 1.3); table "
              f"time {several['table_s'] / single['table_s']:.3f}", flush=True)
    path = results.record("several_imus_rig", medians_s=medians_s, ratios=ratios,
                          parameters={"units": args.units, "buses": args.buses, "transports": transports,
                                      "dwell_s": args.dwell_s, "rate_hz": args.rate_hz, "plan": "short", "runs": 1},
                          note=args.note)
    print(f"figures written to {path}; load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
