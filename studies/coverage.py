"""Coverage study of the uncertainty budget (issue 15): does the truth respect the stated uncertainty?

Many simulated calibrations on the in-memory acquisition path (`bench.sim.acquire`), each
with a new black box (nine angles drawn normal with the level as RMS) and new IMU noise;
per coefficient family, the share of coefficients whose truth lies within the combined
standard uncertainty (1 sigma; 68.3 % for a normal error) and within the expanded
uncertainty (k = 2; 95.4 %). The budget gets the table's part as the true RMS, and
also as 2x and 0.5x of it (a wrong datasheet) from the very same observations. The
table check is studied the same way at 2 s and 10 s dwells.

    PYTHONPATH=. python -m studies.coverage                    # the README's table (about 40 min)
    PYTHONPATH=. python -m studies.coverage --draws 40 --quick  # a few minutes
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from dataclasses import dataclass, field

import numpy as np

from bench.model.earth import Site
from bench.model.families import BODY_AXES, SENSOR_AXES, family_of
from bench.model.imu import NoiseModel, default_sim_imu
from bench.model.table_prior import TablePrior
from bench.model.units import ARCSEC, DEG_PER_HOUR, MICRO_G
from bench.sim.acquire import AcquisitionTiming, acquire
from bench.sim.imu import SimImu
from bench.sim.table import SimTable
from bench.solve.budget import BudgetInputs
from bench.solve.calibrate import solve
from bench.table_check.estimate import NOMINAL_RELATIVE_UNCERTAINTY, conversion_error, true_combinations
from bench.table_check.from_log import analyse_observations
from schedules import load_builtin

SITE = Site(30.27)
PLANS = {"optimal": ("optimal-24", "optimal-5s6r"), "traditional": ("traditional-12", "traditional-3s6r")}
LEVELS_ARCSEC = (0.0, 20.0, 85.0)
PRIOR_FACTORS = (1.0, 2.0, 0.5)
FAMILIES = ("Kg", "D0", "Eg", "Ka", "K0", "Ea")
#: the realistic timing of the study (dwell 60 s as the built-in plan) and the sample rate
TIMING = AcquisitionTiming(dwell_s=60.0, settle_s=5.0, turn_rate_dps=10.0, rest_s=2.0)
QUICK_TIMING = AcquisitionTiming(dwell_s=10.0, settle_s=1.0, move_rate_dps=60.0, move_accel_dps2=40.0,
                                 turn_rate_dps=20.0, turn_accel_dps2=20.0, rest_s=1.0)
RATE_HZ = 100.0


def first_order_names() -> list[str]:
    """The coefficients studied: all but the diagonal direction cosines (a unit row's own
    component moves only at second order, far below every other error)."""
    names = []
    for scale, bias, axes in (("Kg", "D0", "Eg"), ("Ka", "K0", "Ea")):
        names += [f"{scale}_{s}" for s in SENSOR_AXES] + [f"{bias}_{s}" for s in SENSOR_AXES]
        names += [f"{axes}_{a}{s}" for s in SENSOR_AXES for a in BODY_AXES if a.lower() != s]
    return names


@dataclass
class Tally:
    """|error| / sigma of every studied coefficient of every draw, per family."""

    z: dict[str, list[float]] = field(default_factory=lambda: {f: [] for f in FAMILIES})

    def add(self, name: str, error: float, sigma: float) -> None:
        self.z[family_of(name)].append(abs(error) / sigma if sigma > 0 else math.inf)

    def coverage(self, family: str | None = None) -> tuple[int, float, float]:
        """(count, share within 1 sigma, share within 2 sigma) of a family (None: all)."""
        z = np.array(self.z[family] if family else [v for f in FAMILIES for v in self.z.get(f, [])])
        if not len(z):
            return 0, math.nan, math.nan
        return len(z), float(np.mean(z <= 1.0)), float(np.mean(z <= 2.0))


def budget_inputs(noise: NoiseModel, table_arcsec: float, rate_dps: float) -> BudgetInputs:
    return BudgetInputs(table=TablePrior.uniform(table_arcsec, f"{table_arcsec:g} arcsec"),
                        gyro_bias_instability=noise.gyro_bias_instability_dph * DEG_PER_HOUR,
                        acc_bias_instability=noise.acc_bias_instability_ug * MICRO_G,
                        correlation_time_s=noise.correlation_time_s, turn_rate_dps=rate_dps,
                        turn_angle_sigma_rad=0.0)      # the simulated table stops exactly


def calibration_coverage(plan: str, level_arcsec: float, draws: int, seed: int = 0,
                         factors=PRIOR_FACTORS, timing: AcquisitionTiming = TIMING,
                         rate_hz: float = RATE_HZ) -> dict[float, Tally]:
    """Per prior factor, the tally over `draws` simulated calibrations of `plan` (a key of PLANS)."""
    pos_name, rot_name = PLANS[plan]
    positions = [p.angles_deg for p in load_builtin(pos_name).positions]
    turns = list(load_builtin(rot_name).rotations)
    imu, noise = default_sim_imu(), NoiseModel()
    truth = imu.to_canonical()
    names = first_order_names()
    factors = (1.0,) if level_arcsec == 0 else tuple(factors)
    tallies = {f: Tally() for f in factors}
    rng = np.random.default_rng(seed)
    for _ in range(draws):
        box = rng.standard_normal((3, 3)) * level_arcsec * ARCSEC
        sim = SimImu(imu, noise, rate_hz=rate_hz, seed=int(rng.integers(2 ** 32)))
        obs_p, obs_r = acquire(SimTable(SITE, black_box_rad=box), sim, positions, turns, timing)
        for f in factors:
            cal = solve(obs_p, obs_r, SITE, budget_inputs=budget_inputs(noise, f * level_arcsec,
                                                                         timing.turn_rate_dps))
            values, sigmas = cal.values_and_sigmas()
            for name in names:
                tallies[f].add(name, values[name] - truth[name], sigmas[name])
    return tallies


def table_check_coverage(dwell_s: float, draws: int, seed: int = 0, level_arcsec: float = 60.0,
                         rate_hz: float = 200.0, report_every: int = 0) -> Tally:
    """The table check's four combinations against the truth over `draws` simulated checks, per family:
    'check' with the stated sigma (the default conversion uncertainty `NOMINAL_RELATIVE_UNCERTAINTY`),
    'check-true' with the conversion part at the simulated IMU's actual conversion error
    (`conversion_error`: its common x/y scale error against z and in-plane rotation, 4.6e-4 RMS) from the
    same fits, and 'check-noise' with the noise part alone."""
    angles = [p.angles_deg for p in load_builtin("table-check-324").positions]
    timing = AcquisitionTiming(dwell_s=dwell_s, settle_s=1.0)
    imu, noise = default_sim_imu(), NoiseModel()
    true_eps = conversion_error(imu, SITE.gravity)[2]
    tally = Tally(z={"check": [], "check-true": [], "check-noise": []})
    rng = np.random.default_rng(seed)
    for _ in range(draws):
        box = rng.standard_normal((3, 3)) * level_arcsec * ARCSEC
        sim = SimImu(imu, noise, rate_hz=rate_hz, seed=int(rng.integers(2 ** 32)))
        obs, _ = acquire(SimTable(SITE, black_box_rad=box), sim, angles, [], timing)
        est, _ = analyse_observations(obs, SITE.gravity, acc_drift_ug=noise.acc_bias_instability_ug,
                                      correlation_time_s=noise.correlation_time_s)
        errors = np.abs(est.values_rad - true_combinations(box))
        at_true = np.hypot(est.sigma_noise_rad, est.sigma_conversion_rad * true_eps / est.relative_scale_uncertainty)
        tally.z["check"] += list(errors / est.sigma_rad)
        tally.z["check-true"] += list(errors / at_true)
        tally.z["check-noise"] += list(errors / est.sigma_noise_rad)     # already chi2-scaled as sigma
        done = len(tally.z["check"]) // 4
        if report_every and done % report_every == 0 and done < draws:     # a long study shows where it stands
            print(f"# {dwell_s:g} s dwells, {done} draws: " + ", ".join(
                f"{fam} {_pct(c1)} / {_pct(c2)}" for fam in tally.z for _, c1, c2 in [tally.coverage(fam)]),
                flush=True)
    return tally


def _pct(x: float) -> str:
    return "-" if not math.isfinite(x) else f"{100 * x:.1f}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--draws", type=int, default=400, help="simulated calibrations per configuration (400)")
    parser.add_argument("--check-draws", type=int, default=None, help="simulated table checks per dwell "
                        "(default: --draws)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--quick", action="store_true", help="10 s dwells instead of 60 s (faster, less typical)")
    parser.add_argument("--only", choices=("calibration", "check"), help="run one half of the study")
    parser.add_argument("--levels", type=float, nargs="+", default=list(LEVELS_ARCSEC),
                        help="black-box RMS levels, arcsec (default 0 20 85)")
    parser.add_argument("--rate-hz", type=float, default=RATE_HZ, help=f"IMU sample rate (default {RATE_HZ:g})")
    parser.add_argument("--check-dwells", type=float, nargs="+", default=[2.0, 10.0],
                        help="dwells of the table checks, s (default 2 10)")
    parser.add_argument("--check-rate-hz", type=float, default=200.0, help="IMU sample rate of the table checks")
    parser.add_argument("--json", metavar="FILE", help="also write the numbers as JSON")
    args = parser.parse_args(argv)
    timing = QUICK_TIMING if args.quick else TIMING
    started = time.perf_counter()
    print(f"# Coverage study, {time.strftime('%Y-%m-%d')}, {platform.node() or 'this machine'} "
          f"({os.cpu_count()} cores): {args.draws} draws per configuration, dwell {timing.dwell_s:g} s, "
          f"{args.rate_hz:g} Hz, seed {args.seed}")
    print("share of coefficients with |error| <= sigma (target 62-75 %) and <= U = 2 sigma (target 92-98 %)\n")
    print("| plan | black box | table part | " + " | ".join(f"{f} 1s / 2s" for f in FAMILIES) + " | all 1s / 2s |")
    print("|---|---|---|" + "---|" * (len(FAMILIES) + 1))
    out: dict = {"calibration": [], "table_check": []}
    for level in args.levels if args.only != "check" else ():
        for plan in PLANS:
            tallies = calibration_coverage(plan, level, args.draws, args.seed, timing=timing, rate_hz=args.rate_hz)
            for factor, tally in tallies.items():
                cells = []
                row = {"plan": plan, "level_arcsec": level, "prior_factor": factor, "families": {}}
                for fam in FAMILIES + (None,):
                    n, c1, c2 = tally.coverage(fam)
                    cells.append(f"{_pct(c1)} / {_pct(c2)}")
                    row["families"][fam or "all"] = {"n": n, "within_1_sigma": c1, "within_2_sigma": c2}
                out["calibration"].append(row)
                part = "true RMS" if factor == 1 else f"{factor:g} x true"
                print(f"| {plan} | {level:g}\" | {part} | " + " | ".join(cells) + " |", flush=True)
    print("\n| table check | dwell | draws | sigma | within 1 sigma | within 2 sigma |\n|---|---|---|---|---|---|")
    true_eps = conversion_error(default_sim_imu(), SITE.gravity)[2]
    for dwell in args.check_dwells if args.only != "calibration" else ():
        draws = args.check_draws or args.draws
        tally = table_check_coverage(dwell, draws, args.seed, rate_hz=args.check_rate_hz, report_every=50)
        for family, what in (("check", f"stated (conversion {NOMINAL_RELATIVE_UNCERTAINTY:g})"),
                             ("check-true", f"conversion at the IMU's true {true_eps:.2g}"),
                             ("check-noise", "noise part only")):
            n, c1, c2 = tally.coverage(family)
            out["table_check"].append({"dwell_s": dwell, "draws": draws, "sigma": what, "n": n,
                                       "within_1_sigma": c1, "within_2_sigma": c2})
            print(f"| 60\" black box, 324 positions, {args.check_rate_hz:g} Hz | {dwell:g} s | {draws} | {what} | "
                  f"{_pct(c1)} | {_pct(c2)} |", flush=True)
    print(f"\n{time.perf_counter() - started:.0f} s")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=2)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
