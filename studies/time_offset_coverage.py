"""Coverage of the gyro-to-accelerometer time offset's uncertainty, and `--model auto` with the offset off (issue 30).

Per grade (`bench.model.higher_order.GRADES`, all its higher-order truth on, its noise class), N simulated
calibrations (independent noise draws) of a plan that sees the offset: the optimal 24 positions and the optimal
5-state-6-rotation turns, plus turns across gravity in both directions (the middle frame from (0, 0, 0), the inner
frame from (0, 90, 0)) at 10 and 20 deg/s, each turn reduced to its timing against the table's angle
(`bench.model.turn_timing`). Each draw is solved with `[model] terms = ["time_offset"]` and the estimate compared
with the truth: within U (k = 2; expected 95 %), within 1 sigma (expected 68 %). With the offset set to 0 (the
other terms still on) it counts how often `auto` adds the time offset (expected about ALPHA = 0.5 %).

    PYTHONPATH=. python -m studies.time_offset_coverage --draws 10                     # a few minutes
    PYTHONPATH=. python -m studies.time_offset_coverage --draws 200 --offsets-ms 0.05 0.5 2 0 --auto-off
    PYTHONPATH=. python -m studies.time_offset_coverage --draws 40 --spread          # is each sigma the spread?
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from types import SimpleNamespace

from bench.model.higher_order import GRADES, HigherOrderTerms, preset
from bench.model.imu import default_sim_imu
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.budget import BudgetInputs
from bench.solve.extended import solve_extended
from bench.solve.time_offset import acc_delay, gyro_delay
from schedules import load_builtin
from studies.extended_coverage import NOISE, SITE

#: turns about axes across gravity, each from one start in both directions: what tells the offset
ACROSS_GRAVITY = [SimpleNamespace(start_deg=start, frame=frame, direction=direction, revolutions=1)
                  for start, frame in (((0.0, 0.0, 0.0), "middle"), ((0.0, 90.0, 0.0), "inner"))
                  for direction in ("ccw", "cw")]
RATES_DPS = (10.0, 20.0)
K = 2.0


def observe(grade: str, offset_ms: float | None, seed: int, rate_hz: float = 100.0
            ) -> tuple[list[PositionObservation], list[RotationObservation], BudgetInputs]:
    """One simulated acquisition: the grade's higher-order truth with the offset `offset_ms` (None: the preset's)."""
    noise = NOISE[grade]
    values = preset(grade)
    if offset_ms is not None:
        values["time_offset_ms"] = offset_ms
    imu = SimImu(default_sim_imu(), noise, rate_hz=rate_hz, seed=seed,
                 higher_order=HigherOrderTerms.from_display(values))
    table = SimTable(SITE)
    positions = [p.angles_deg for p in load_builtin("optimal-24").positions]
    turns = [*load_builtin("optimal-5s6r").rotations, *ACROSS_GRAVITY]
    timing = dataclasses.replace(AcquisitionTiming(), turn_rate_dps=RATES_DPS[0])
    observed_positions, observed_turns = acquire(table, imu, positions, turns, timing, turn_timings=True)
    for rate in RATES_DPS[1:]:
        _, more = acquire(table, imu, [], ACROSS_GRAVITY, dataclasses.replace(timing, turn_rate_dps=rate),
                          turn_timings=True)
        observed_turns += [dataclasses.replace(o, label=f"R{len(observed_turns) + k + 1:02d}")
                           for k, o in enumerate(more)]
    budget = BudgetInputs(gyro_bias_instability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                          acc_bias_instability=noise.acc_bias_instability_ug * MICRO_G,
                          correlation_time_s=noise.correlation_time_s, turn_angle_sigma_rad=0.0)
    return observed_positions, observed_turns, budget


def coverage(grade: str, offset_ms: float | None, draws: int, seed: int, rate_hz: float
             ) -> tuple[int, int, list[float], list[float]]:
    """(inside U, inside 1 sigma, estimates ms, sigmas ms) over `draws` calibrations."""
    truth = float(preset(grade)["time_offset_ms"]) if offset_ms is None else offset_ms   # type: ignore[arg-type]
    in_u = in_1 = 0
    values, sigmas = [], []
    for draw in range(draws):
        positions, turns, budget = observe(grade, offset_ms, seed + draw, rate_hz)
        value, sigma = (x["Dt"] for x in solve_extended(positions, turns, SITE, ["time_offset"],
                                                         budget_inputs=budget).values_and_sigmas())
        z = abs(value - truth) / sigma
        in_u += z <= K
        in_1 += z <= 1.0
        values.append(value)
        sigmas.append(sigma)
    return in_u, in_1, values, sigmas


def spread(grade: str, draws: int, seed: int, rate_hz: float) -> dict[str, tuple[float, float, float]]:
    """The turns across gravity alone, offset off: per part (tau_a, tau_g, Dt) its mean, the spread of its estimates
    and its mean sigma over `draws` (ms): an honest sigma is about the spread."""
    noise = NOISE[grade]
    values = preset(grade)
    values["time_offset_ms"] = 0.0
    found: dict[str, list[tuple[float, float]]] = {"tau_a": [], "tau_g": [], "Dt": []}
    for draw in range(draws):
        imu = SimImu(default_sim_imu(), noise, rate_hz=rate_hz, seed=seed + draw,
                     higher_order=HigherOrderTerms.from_display(values))
        table = SimTable(SITE)
        turns: list[RotationObservation] = []
        for rate in RATES_DPS:
            turns += acquire(table, imu, [], ACROSS_GRAVITY,
                             dataclasses.replace(AcquisitionTiming(), turn_rate_dps=rate), turn_timings=True)[1]
        tau_a, _, var_a, _ = acc_delay(turns)
        tau_g, _, var_g = gyro_delay(turns)
        for key, value, var in (("tau_a", tau_a, var_a), ("tau_g", tau_g, var_g),
                                ("Dt", tau_a - tau_g, var_a + var_g)):
            found[key].append((value * 1e3, math.sqrt(var) * 1e3))
    out = {}
    for key, rows in found.items():
        estimates = [v for v, _ in rows]
        mean = sum(estimates) / len(estimates)
        std = math.sqrt(sum((v - mean) ** 2 for v in estimates) / max(len(estimates) - 1, 1))
        out[key] = (mean, std, sum(s for _, s in rows) / len(rows))
    return out


def auto_adds(grade: str, draws: int, seed: int, rate_hz: float) -> int:
    """Draws with the offset off (the grade's other terms on) in which `auto` kept the time offset."""
    added = 0
    for draw in range(draws):
        positions, turns, budget = observe(grade, 0.0, seed + draw, rate_hz)
        fit = solve_extended(positions, turns, SITE, "auto", budget_inputs=budget).extended
        assert fit is not None
        added += "time_offset" in fit.terms
    return added


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grades", nargs="*", default=list(GRADES), choices=list(GRADES))
    parser.add_argument("--offsets-ms", nargs="*", type=float, default=[math.nan, 2.0, 0.0],
                        help="the true offsets (nan: the grade's preset)")
    parser.add_argument("--draws", type=int, default=10)
    parser.add_argument("--seed", type=int, default=300)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--auto-off", action="store_true", help="also how often auto adds it with the offset off")
    parser.add_argument("--spread", action="store_true",
                        help="only the spread of the estimates against their sigma (the turns alone, offset off)")
    args = parser.parse_args(argv)
    if args.spread:
        print("| grade | part | mean ms | spread ms | mean sigma ms | draws |\n|---|---|---|---|---|---|")
        for grade in args.grades:
            for key, (mean, std, sigma) in spread(grade, args.draws, args.seed, args.rate_hz).items():
                print(f"| {grade} | {key} | {mean:.4f} | {std:.4f} | {sigma:.4f} | {args.draws} |", flush=True)
        return
    print("| grade | true offset ms | within U | within 1 sigma | mean estimate ms | mean sigma ms | draws |\n"
          "|---|---|---|---|---|---|---|")
    for grade in args.grades:
        for offset in args.offsets_ms:
            chosen = None if math.isnan(offset) else offset
            in_u, in_1, values, sigmas = coverage(grade, chosen, args.draws, args.seed, args.rate_hz)
            truth = preset(grade)["time_offset_ms"] if chosen is None else chosen
            print(f"| {grade} | {truth} | {100 * in_u / args.draws:.0f} % | {100 * in_1 / args.draws:.0f} % | "
                  f"{sum(values) / len(values):.4f} | {sum(sigmas) / len(sigmas):.4f} | {args.draws} |", flush=True)
    if args.auto_off:
        for grade in args.grades:
            added = auto_adds(grade, args.draws, args.seed, args.rate_hz)
            print(f"auto, {grade}, offset off: time_offset added in {added} of {args.draws} draws", flush=True)


if __name__ == "__main__":
    main()
