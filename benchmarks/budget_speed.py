"""Benchmark: what the uncertainty budget adds to a run's solve time (target < 10 %).

Run: python benchmarks/budget_speed.py [--repeats 7] [--log RUN.mcap]
Records the default simulated plan once (`bench run --sim`: optimal-24 + optimal-5s6r,
dwell 60 s, 200 Hz, the table's part from the simulated black box), unless --log names a
log. Then, side by side in one process, `repeats` times each: the run's solve from the log
(`solve_logs`: read, decode, extract, solve, budget: what `bench run` does after the run)
and the budget alone (`compute_budget` on the same solved fits). Prints the medians and
the budget's share of the rest of the solve.
"""

from __future__ import annotations

import argparse
import glob
import statistics
import subprocess
import sys
import tempfile
import time

import results


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--log", help="a recorded run log (default: record the default simulated plan)")
    args = parser.parse_args()
    from bench.log.reader import read_log
    from bench.log.run_info import layout_and_config_from_log
    from bench.solve.budget import compute_budget
    from bench.solve.from_logs import solve_logs
    from bench.solve.inputs import budget_inputs

    with tempfile.TemporaryDirectory() as out:
        path = args.log
        if path is None:
            subprocess.run([sys.executable, "-m", "bench.cli", "run", "--sim", "--quiet", "--out", out], check=False)
            path = glob.glob(f"{out}/*.mcap")[0]
        log = read_log(path)
        setup = layout_and_config_from_log(log)
        inputs = budget_inputs(setup.config, log.metadata.get("run", {}).get("mode") == "simulator")
        solves, budgets = [], []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            solution = solve_logs([read_log(path)], setup.site, setup.layout, setup.rate_hz, budget=inputs)
            solves.append(time.perf_counter() - t0)
            cal = solution.calibration
            t0 = time.perf_counter()
            compute_budget(cal.accelerometers, cal.gyros, cal.gyro_bias, cal.positions, cal.rotations, setup.site,
                           inputs)
            budgets.append(time.perf_counter() - t0)
    solve_s, budget_s = statistics.median(solves), statistics.median(budgets)
    share = budget_s / (solve_s - budget_s)
    print(f"{len(cal.positions)} positions, {len(cal.rotations)} turns, {inputs.mc_draws} Monte-Carlo draws")
    print(f"solve from the log (with the budget): median {solve_s * 1e3:.1f} ms over {args.repeats}")
    print(f"the budget alone:                     median {budget_s * 1e3:.1f} ms")
    print(f"the budget adds {100 * share:.1f} % to the rest of the solve (target < 10 %: "
          f"{'met' if share < 0.10 else 'MISSED'})")
    path = results.record("budget_speed", medians_s={"solve from the log, with the budget": solve_s,
                                                      "the uncertainty budget alone": budget_s},
                          ratios={"budget / rest of the solve": share},
                          parameters={"repeats": args.repeats, "log": args.log or "the default simulated plan"})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
