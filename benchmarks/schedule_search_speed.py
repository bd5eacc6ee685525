"""Benchmark: the exhaustive schedule search (not a test). Run: python benchmarks/schedule_search_speed.py"""

import time

import results

from bench.schedule_design.search import combo_of_angles, combo_of_turns, search_positions, search_rotations
from schedules import load_builtin


def main() -> None:
    started = time.perf_counter()
    pos = search_positions()
    rot = search_rotations()
    wall = time.perf_counter() - started
    paper_pos = combo_of_angles([p.angles_deg for p in load_builtin("optimal-24").positions])
    paper_rot = combo_of_turns(load_builtin("optimal-5s6r").rotations)
    print(f"positions: {pos.total:,} choices in {pos.elapsed_s:.1f} s ({pos.total / pos.elapsed_s:,.0f} combos/s); "
          f"counts {pos.counts}; Table 1 optimal: {paper_pos in {tuple(x) for x in pos.optimal}}")
    print(f"rotations: {rot.total:,} choices in {rot.elapsed_s:.1f} s ({rot.total / rot.elapsed_s:,.0f} combos/s); "
          f"counts {rot.counts}; Table 3 optimal: {paper_rot in {tuple(sorted(x)) for x in rot.optimal}}")
    print(f"wall time {wall:.1f} s")
    path = results.record("schedule_search_speed", medians_s={
        "exhaustive position search (one run)": pos.elapsed_s, "exhaustive rotation search (one run)": rot.elapsed_s,
        "both, wall time": wall}, ratios={"position combinations per s": pos.total / pos.elapsed_s,
                                          "rotation combinations per s": rot.total / rot.elapsed_s},
        note="one run each, not a median: the search takes its time once")
    print(f"figures written to {path}")


if __name__ == "__main__":
    main()
