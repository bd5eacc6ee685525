"""Benchmark: total plan duration, travel-ordered vs the paper's listing order vs the lower bound.

Run: python benchmarks/plan_duration.py [--repeats 5]
Timing: dwell 60 s, settle 5 s, moves 20 deg/s at 10 deg/s^2 (+0.5 s command overhead
per move), turns 10 deg/s at 5 deg/s^2, 1 revolution, rest 2 s; start at (0, 0, 0),
continuous axes. The lower bound is dwells + settles + turns (no moves at all).
"""

from __future__ import annotations

import argparse
import statistics
import time

import results

PLANS = (("optimal-24", "optimal-5s6r"), ("traditional-12", "traditional-3s6r"), ("all-64", "all-96"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()

    from bench.model.units import format_hms
    from bench.plan.compiler import PlanTiming, compile_plan
    from schedules import load_builtin

    timing = PlanTiming(dwell_s=60, settle_s=5, move_rate_dps=20, move_accel_dps2=10, turn_rate_dps=10,
                        turn_accel_dps2=5, rest_s=2, revolutions=1)
    print(f"{'plan':<34} {'ordered':>17} {'listing order':>17} {'lower bound':>17} {'saving':>7} "
          f"{'ord/LB':>7} {'moves ord/listed':>17} {'compile':>10}")
    medians_s: dict[str, float] = {}
    ratios: dict[str, float] = {}
    for positions_name, rotations_name in PLANS:
        positions, rotations = load_builtin(positions_name), load_builtin(rotations_name)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            plan = compile_plan(positions, rotations, timing)
            times.append(time.perf_counter() - t0)
        listed = compile_plan(positions, rotations, timing, order="listed")
        saving = 100.0 * (plan.listed_total_s - plan.estimated_total_s) / plan.listed_total_s

        def cell(seconds: float) -> str:
            return f"{format_hms(seconds)} ({seconds:.0f} s)"

        print(f"{positions_name + ' + ' + rotations_name:<34} {cell(plan.estimated_total_s):>17} "
              f"{cell(plan.listed_total_s):>17} {cell(plan.lower_bound_s):>17} {saving:>6.1f}% "
              f"{plan.estimated_total_s / plan.lower_bound_s:>7.3f} "
              f"{f'{plan.move_total_s:.1f} / {listed.move_total_s:.1f} s':>17} "
              f"{statistics.median(times) * 1e3:>7.1f} ms")
        name = f"{positions_name} + {rotations_name}"
        medians_s[f"{name}: compile"] = statistics.median(times)
        ratios[f"{name}: ordered / lower bound"] = plan.estimated_total_s / plan.lower_bound_s
        ratios[f"{name}: ordered / listing order"] = plan.estimated_total_s / plan.listed_total_s
    print(f"compile time: median of {args.repeats}, in process, includes compiling the listing order too")
    path = results.record("plan_duration", medians_s=medians_s, ratios=ratios, parameters={"repeats": args.repeats})
    print(f"figures written to {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
