"""Coverage of the extended model's uncertainty and the false-add rate of `--model auto` (issue 30, must show 2-3).

Per grade (`bench.model.higher_order.GRADES`), N simulated calibrations (independent noise draws) of the shipped
extended plan (`schedules/extended-44.toml`: the optimal 24 positions plus 20 tilts of 45 deg;
`schedules/extended-5s6r-2rates.toml`: the optimal 5-state-6-rotation turns at 10 and at 40 deg/s). Each is
solved with every family its windows show (`bench.model.extended.MEAN_TERMS`; the time offset has its own study,
`studies.time_offset_coverage`); per family it counts how often the truth lies
within U (k = 2; expected 95 %) and within 1 sigma (expected 68 %). With `--auto-off`, the same plan with the
higher-order truth off, solved with `auto`: how often it adds a family (expected at most 5 %).

    PYTHONPATH=. python -m studies.extended_coverage --draws 20                 # about 2 min per grade at 100 Hz
    PYTHONPATH=. python -m studies.extended_coverage --draws 200 --auto-off     # the must-show run (hours)
"""

from __future__ import annotations

import argparse
import dataclasses

from bench.model.earth import Site
from bench.model.extended import FAMILIES, MEAN_TERMS, TERMS
from bench.model.families import BODY_AXES, SENSOR_AXES
from bench.model.higher_order import GRADES, HigherOrderTerms, preset
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.observations import PositionObservation, RotationObservation
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.budget import BudgetInputs
from bench.solve.extended import solve_extended
from schedules import resolve_schedule

SITE = Site(30.27)
#: the shipped extended plan (extended.example.toml's): positions with 45-deg tilts, turns at two rates
PLAN = ("extended-44", "extended-5s6r-2rates")
#: the noise of each grade's class ("off": none); the MEMS unit keeps pulse outputs (see studies.higher_order_bias)
NOISE = {"off": NoiseModel.off(), "nav-fog": NoiseModel(),
         "tactical-mems": dataclasses.replace(NoiseModel.mems(), quantise=True)}


def truth_values(terms: HigherOrderTerms) -> dict[str, float]:
    """The extended coefficients of a simulated IMU's higher-order truth, in result units."""
    out: dict[str, float] = {}
    for i, s in enumerate(SENSOR_AXES):
        for term, value in (("gyro_asymmetry", terms.gyro_asymmetry[i]),
                            ("gyro_nonlinearity", terms.gyro_nonlinearity[i]),
                            ("acc_asymmetry", terms.acc_asymmetry[i]), ("acc_second_order", terms.acc_second_order[i]),
                            ("acc_lever_arm", terms.acc_lever_arm[i, i])):
            out[f"{FAMILIES[term].key}_{s}"] = value / FAMILIES[term].result_to_si
        for j, a in enumerate(BODY_AXES):
            out[f"Gg_{a}{s}"] = terms.gyro_g_sensitivity[i, j] / FAMILIES["gyro_g_sensitivity"].result_to_si
            if i != j:
                out[f"Ca_{a}{s}"] = terms.acc_cross[i, j] / FAMILIES["acc_cross"].result_to_si
    return out


def observe(noise_name: str, grade: str | None, seed: int = 3, plan: tuple[str, str] = PLAN,
            rate_hz: float = 100.0) -> tuple[list[PositionObservation], list[RotationObservation], BudgetInputs,
                                             HigherOrderTerms | None]:
    """One simulated acquisition of a plan (positions, rotations: schedule names or files; the turns at their own
    rates), in the listed order: observations, the budget's inputs, the truth."""
    noise = NOISE[noise_name]
    terms = HigherOrderTerms.from_display(preset(grade)) if grade else None
    imu = SimImu(default_sim_imu(), noise, rate_hz=rate_hz, seed=seed, higher_order=terms)
    positions = [p.angles_deg for p in resolve_schedule(plan[0]).positions]
    turns = list(resolve_schedule(plan[1]).rotations)
    observed_positions, observed_turns = acquire(SimTable(SITE), imu, positions, turns, AcquisitionTiming())
    budget = BudgetInputs(gyro_bias_instability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                          acc_bias_instability=noise.acc_bias_instability_ug * MICRO_G,
                          correlation_time_s=noise.correlation_time_s, turn_angle_sigma_rad=0.0)
    return observed_positions, observed_turns, budget, terms


def coverage(grade: str, draws: int, seed: int, rate_hz: float) -> dict[str, tuple[int, int, int]]:
    """family -> (inside U, inside 1 sigma, coefficients counted) over `draws` calibrations."""
    counts = {t: [0, 0, 0] for t in MEAN_TERMS}
    for draw in range(draws):
        positions, turns, budget, terms = observe(grade, grade, seed=seed + draw, rate_hz=rate_hz)
        assert terms is not None
        values, sigmas = solve_extended(positions, turns, SITE, MEAN_TERMS, budget_inputs=budget).values_and_sigmas()
        for name, true in truth_values(terms).items():
            family = next(f.term for f in FAMILIES.values() if name in f.names)
            z = abs(values[name] - true) / sigmas[name]
            counts[family][0] += z <= 2.0
            counts[family][1] += z <= 1.0
            counts[family][2] += 1
    return {t: (c[0], c[1], c[2]) for t, c in counts.items()}


def auto_false_adds(draws: int, seed: int, rate_hz: float) -> tuple[int, dict[str, int]]:
    """Draws (truth off, nav-fog noise) in which `auto` added a family, and how often each was added."""
    added = 0
    per_family = dict.fromkeys(TERMS, 0)
    for draw in range(draws):
        positions, turns, budget, _ = observe("nav-fog", None, seed=seed + draw, rate_hz=rate_hz)
        fit = solve_extended(positions, turns, SITE, "auto", budget_inputs=budget).extended
        assert fit is not None
        added += bool(fit.terms)
        for term in fit.terms:
            per_family[term] += 1
    return added, per_family


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grades", nargs="*", default=list(GRADES), choices=list(GRADES))
    parser.add_argument("--draws", type=int, default=20)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    parser.add_argument("--auto-off", action="store_true", help="also the false-add rate of auto, truth off")
    args = parser.parse_args(argv)
    for grade in args.grades:
        print(f"### {grade}: {args.draws} draws\n")
        print("| family | within U | within 1 sigma | coefficients |\n|---|---|---|---|")
        for term, (in_u, in_1, n) in coverage(grade, args.draws, args.seed, args.rate_hz).items():
            print(f"| {term} | {100 * in_u / n:.0f} % | {100 * in_1 / n:.0f} % | {n} |")
        print()
    if args.auto_off:
        added, per_family = auto_false_adds(args.draws, args.seed, args.rate_hz)
        print(f"auto, truth off: a family added in {added} of {args.draws} draws "
              f"({100 * added / args.draws:.0f} %); per family {per_family}")


if __name__ == "__main__":
    main()
