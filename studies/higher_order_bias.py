"""The bias the higher-order IMU errors induce in the 30-coefficient solve (issue 30, "must show" 1).

Per grade (`bench.model.higher_order.GRADES`) and per term of it (then all together), one simulated calibration
of the default plan (optimal-24 + optimal-5s6r, the default plan timing) with the term on, and one with every
term off on the same seed (the same noise draws): the difference of each coefficient is the bias the term
induces, given in units of the clean run's sigma; `flag` is the residual test of the run with the term on
(the fits whose residuals are inconsistent with the uncertainty budget). The simulated IMU is the built-in one
with the noise of the grade's class (`UNITS`); the `--rate-hz` default keeps a run to seconds (the bias and the
white-noise sigmas do not depend on the rate: nav-fog's K0 biases are the same at 100 Hz and 1 kHz to 0.1 sigma).
One draw: a difference below about 0.3 sigma is not the term's (the same noise draws, but the quantiser's carried
remainder takes other values once a term changes any earlier output), and a residual test fails by chance in about
1 % of fits.

    PYTHONPATH=. python -m studies.higher_order_bias                    # both grades, 100 Hz, about a minute
    PYTHONPATH=. python -m studies.higher_order_bias --rate-hz 1000 --grades nav-fog
"""

from __future__ import annotations

import argparse
import dataclasses
from dataclasses import dataclass

from bench.model.earth import Site
from bench.model.higher_order import GRADES, HigherOrderTerms, preset
from bench.model.imu import ImuCoefficients, NoiseModel, default_sim_imu
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.budget import BudgetInputs
from bench.solve.calibrate import Calibration, solve
from schedules import load_builtin

SITE = Site(30.27)
#: grade -> the simulated IMU and its noise: the built-in FOG IMU; for the MEMS grade its pulse outputs with the
#: MEMS noise (the in-memory acquisition takes each output as integer counts, so an IMU sending SI units would get
#: a resolution floor of one m/s^2 / s on every mean)
UNITS: dict[str, tuple[ImuCoefficients, NoiseModel]] = {
    "nav-fog": (default_sim_imu(), NoiseModel()),
    "tactical-mems": (default_sim_imu(), dataclasses.replace(NoiseModel.mems(), quantise=True))}


@dataclass
class Row:
    term: str
    bias_sigma: dict[str, float]      # coefficient -> (value on - value off) / sigma off
    flags: list[str]                  # "accelerometers x", ... : residual test failed

    def largest(self, count: int = 3) -> list[tuple[str, float]]:
        return sorted(self.bias_sigma.items(), key=lambda item: -abs(item[1]))[:count]


def calibrate(grade: str, terms: HigherOrderTerms | None, seed: int, rate_hz: float,
              timing: AcquisitionTiming) -> Calibration:
    """One simulated calibration of the default plan by the grade's simulated IMU."""
    positions = [p.angles_deg for p in load_builtin("optimal-24").positions]
    turns = list(load_builtin("optimal-5s6r").rotations)
    coefficients, noise = UNITS[grade]
    imu = SimImu(coefficients, noise, rate_hz=rate_hz, seed=seed, higher_order=terms)
    observed_positions, observed_turns = acquire(SimTable(SITE), imu, positions, turns, timing)
    # the budget as `bench run --sim` has it on an ideal simulated table: the noise's bias instabilities, turns
    # ending where told, the site exact
    budget = BudgetInputs(gyro_bias_instability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                          acc_bias_instability=noise.acc_bias_instability_ug * MICRO_G,
                          correlation_time_s=noise.correlation_time_s, turn_rate_dps=timing.turn_rate_dps,
                          turn_angle_sigma_rad=0.0)
    return solve(observed_positions, observed_turns, SITE, budget_inputs=budget)


def study(grade: str, seed: int, rate_hz: float, timing: AcquisitionTiming,
          terms: list[str] | None = None) -> list[Row]:
    """The reference row, one row per term of the grade (`terms`: only these) and, for all terms, "all"."""
    clean = calibrate(grade, None, seed, rate_hz, timing)
    clean_values, clean_sigmas = clean.values_and_sigmas()
    values = preset(grade)
    rows = [Row("none (the reference run)", dict.fromkeys(clean_values, 0.0), _flags(clean))]
    for term in [*values, "all"] if terms is None else terms:
        chosen = values if term == "all" else {term: values[term]}
        calibration = calibrate(grade, HigherOrderTerms.from_display(chosen), seed, rate_hz, timing)
        on_values, _ = calibration.values_and_sigmas()
        bias = {name: (on_values[name] - clean_values[name]) / clean_sigmas[name]
                for name in clean_values if clean_sigmas[name] > 0}
        rows.append(Row(term, bias, _flags(calibration)))
    return rows


def _flags(calibration: Calibration) -> list[str]:
    """The fits whose residual test fails."""
    return [f"{c.fit} {c.sensor}" for c in calibration.budget.inconsistent()] if calibration.budget else []


def table(grade: str, rows: list[Row]) -> str:
    lines = [f"### {grade}", "", "| term on | largest biases (sigma) | max abs | residual test |", "|---|---|---|---|"]
    for row in rows:
        top = ", ".join(f"{name} {value:+.1f}" for name, value in row.largest()) if any(row.bias_sigma.values()) \
            else "-"
        worst = max(abs(v) for v in row.bias_sigma.values())
        lines.append(f"| {row.term} | {top} | {worst:.1f} | {'; '.join(row.flags) or 'consistent'} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grades", nargs="+", default=list(GRADES), choices=list(GRADES))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rate-hz", type=float, default=100.0)
    args = parser.parse_args(argv)
    timing = AcquisitionTiming()
    for grade in args.grades:
        print(table(grade, study(grade, args.seed, args.rate_hz, timing)))
        print()


if __name__ == "__main__":
    main()
