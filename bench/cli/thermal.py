"""`bench thermal`: calibration over temperature (logic in `bench.thermal`).

`bench thermal sim --temperatures-c -20 0 25 50 --out DIR` calibrates the simulated IMU,
soaked at each temperature, in memory, and fits the thermal model; `bench thermal fit
RESULT[@DEGC]... --out DIR` fits it to calibration results from disk. Both write
`thermal.json` (format turntable-bench/thermal), `thermal.md` and `thermal.html`;
`sim` also each temperature's `sim_<T>C.result.json`. `bench thermal eval THERMAL.json
--temperature-c T` prints every coefficient at T with its 1-sigma. Exit codes: 0 done, 2 usage
error, a configuration or a result that cannot be used.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time
from pathlib import Path

from bench.calibration.compensation import load_result
from bench.cli.common import ExitCode, fail, number_type
from bench.errors import InputError
from bench.files import OutputFileError, make_output_folder

PROG = "bench thermal"
#: the temperatures a bench can mean, degC (`bench.config.thermal` says the same for [sim.imu.thermal])
_TEMPERATURE = number_type("a temperature from -100 to 200 degC", lambda value: -100.0 <= value <= 200.0)


def _temperatures(text: str) -> list[float]:
    values = [_TEMPERATURE(part.strip()) for part in text.split(",") if part.strip()]
    if len({round(v, 6) for v in values}) < 2:
        raise argparse.ArgumentTypeError(f"needs two different temperatures at least, got {text!r}")
    if len(values) > 50:
        raise argparse.ArgumentTypeError(f"at most 50 temperatures, got {len(values)}")
    return values


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "thermal",
        description="Fit every coefficient against the IMU's temperature (a polynomial of degree 0..3 chosen by the "
                    "data, with its covariance and band) from calibrations at several temperatures: simulated "
                    "(sim) or result files (fit). Writes thermal.json, thermal.md and thermal.html; `bench export "
                    "thermal.json` writes the model for firmware. Exit codes: 0 done, 2 usage error or an input "
                    "that cannot be used.")
    sub = parser.add_subparsers(dest="thermal_command", metavar="{sim,fit,eval}")
    sub.required = True
    sim = sub.add_parser("sim", help="calibrate the simulated IMU soaked at each temperature, then fit",
                         description="In memory, without a chamber: the simulated IMU (its [sim.imu.thermal], or a "
                                     "built-in demonstration model) is soaked at each temperature and calibrated "
                                     "with the configuration's schedules; each run is solved and the thermal model "
                                     "fitted.")
    sim.add_argument("--temperatures-c", nargs="+", required=True, metavar="T",
                     help="temperatures, degC: -20 0 25 50 (or --temperatures-c=-20,0,25,50)")
    sim.add_argument("--config", metavar="FILE", help="bench configuration (default: the built-in sim configuration)")
    sim.add_argument("--seed", type=int, default=None, help="random seed (default: the configuration's [sim] seed)")
    sim.add_argument("--reference-c", type=_TEMPERATURE, default=None,
                     help="reference temperature of the fitted polynomials (default: the simulated IMU's)")
    sim.add_argument("--out", metavar="DIR", required=True, help="output folder (created if missing)")
    sim.add_argument("--quiet", action="store_true", help="print nothing but errors")
    sim.set_defaults(func=cmd_thermal_sim)
    fit = sub.add_parser("fit", help="fit the thermal model to calibration results",
                         description="Each RESULT is a result file (<run-id>.result.json) whose 'temperature' "
                                     "section gives the IMU's mean temperature, or RESULT@DEGC to give it.")
    fit.add_argument("results", nargs="+", metavar="RESULT[@DEGC]", help="result files, two temperatures at least")
    fit.add_argument("--reference-c", type=_TEMPERATURE, default=25.0,
                     help="reference temperature of the polynomials, degC (default 25)")
    fit.add_argument("--out", metavar="DIR", required=True, help="output folder (created if missing)")
    fit.add_argument("--quiet", action="store_true", help="print nothing but errors")
    fit.set_defaults(func=cmd_thermal_fit)
    ev = sub.add_parser("eval", help="every modelled coefficient at a temperature, with its 1-sigma",
                        description="Evaluate a thermal model (thermal.json) at a temperature: value and 1-sigma of "
                                    "every coefficient; outside the calibrated range the output says so.")
    ev.add_argument("model", metavar="THERMAL.json", help="a thermal model from `bench thermal sim|fit`")
    ev.add_argument("--temperature-c", type=_TEMPERATURE, required=True, metavar="T", help="IMU temperature, degC")
    ev.set_defaults(func=cmd_thermal_eval)


def _out_dir(text: str) -> Path | None:
    """The output folder, made if missing (None when it cannot be: said in one line)."""
    try:
        return make_output_folder(text)
    except OutputFileError as exc:
        fail(PROG, str(exc), ExitCode.USAGE)
        return None


def _summary(model) -> list[str]:
    low, high = model.range_c
    degrees: dict[int, list[str]] = {}
    for name, fit in model.fits.items():
        degrees.setdefault(fit.degree, []).append(name)
    lines = [f"thermal model: {len(model.fits)} coefficients, {len(model.points)} calibrations from {low:g} to "
             f"{high:g} degC, polynomials in (T - {model.reference_c:g} degC)"]
    lines += [f"  degree {d}: {', '.join(names)}" for d, names in sorted(degrees.items())]
    lines += [f"  note: {n}" for n in model.notes]
    return lines


def _write(model, out: Path, quiet: bool) -> None:
    # heavy (scipy, python-can, matplotlib): imported when the command runs, not for its --help
    from bench.report.thermal import write_thermal_reports

    path = out / "thermal.json"
    model.save(path)
    written = [path] + write_thermal_reports(model, out)
    if not quiet:
        print("\n".join(_summary(model)))
        print("wrote " + ", ".join(str(p) for p in written))


def cmd_thermal_sim(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can): imported when the command runs, not for its --help
    from bench.config.load import default_sim_config, load_config
    from bench.thermal.simulate import DEMO_THERMAL, simulate_thermal

    try:
        temperatures_c = _temperatures(",".join(args.temperatures_c))
    except argparse.ArgumentTypeError as exc:
        return fail(PROG, f"--temperatures-c: {exc}", ExitCode.USAGE)
    try:
        config = load_config(args.config) if args.config else default_sim_config()
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    if args.seed is not None:
        if not 0 <= args.seed <= 2 ** 32 - 1:
            return fail(PROG, f"--seed must be 0..4294967295, got {args.seed}", ExitCode.USAGE)
        config = dataclasses.replace(config, sim=dataclasses.replace(config.sim, seed=args.seed))
    out = _out_dir(args.out)
    if out is None:
        return ExitCode.USAGE
    if not args.quiet and config.sim.thermal is None:
        print("the configuration has no [sim.imu.thermal]: using the built-in demonstration model "
              "(bench.thermal.simulate.DEMO_THERMAL)")
    started = last = time.perf_counter()

    def progress(k: int, point) -> None:
        nonlocal last
        setpoint_c = point.result.run.extra["temperature_setpoint_c"]
        name = f"sim_{setpoint_c:g}C.result.json"
        point.result.save(out / name)
        now = time.perf_counter()
        if not args.quiet:
            print(f"{setpoint_c:g} degC: IMU mean {point.temperature_c:.3f} degC, "
                  f"solved, wrote {out / name} (this temperature {now - last:.1f} s, {now - started:.1f} s in all)",
                  flush=True)
        last = now

    try:
        model = simulate_thermal(config, temperatures_c, thermal=config.sim.thermal or DEMO_THERMAL,
                                 reference_c=args.reference_c, progress=progress)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    _write(model, out, args.quiet)
    return ExitCode.OK


def _split(text: str) -> tuple[str, float | None]:
    """'r.json@-20' -> ('r.json', -20.0); a name whose part after its last '@' is no number stays whole."""
    head, at, tail = text.rpartition("@")
    if at and head:
        try:
            value = float(tail)
        except ValueError:
            return text, None
        if not math.isfinite(value):
            raise InputError(f"{text}: the temperature after '@' must be a finite number")
        return head, value
    return text, None


def cmd_thermal_fit(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.thermal.model import fit_thermal_model, point_from_result

    points = []
    try:
        for text in args.results:
            path, temperature_c = _split(text)
            try:
                result = load_result(path)
            except OSError as exc:
                return fail(PROG, f"{path}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
            points.append(point_from_result(result, Path(path).name, temperature_c))
        model = fit_thermal_model(points, args.reference_c)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    model.run = {"mode": "fitted to result files", "results": [p.label for p in model.points]}
    out = _out_dir(args.out)
    if out is None:
        return ExitCode.USAGE
    _write(model, out, args.quiet)
    return ExitCode.OK


def cmd_thermal_eval(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.thermal.model import ThermalModel

    try:
        model = ThermalModel.load(args.model)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.model}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
    low, high = model.range_c
    t = args.temperature_c
    where = "inside" if low <= t <= high else "OUTSIDE (extrapolated)"
    print(f"at {t:g} degC, {where} the calibrated range {low:g} to {high:g} degC; value +- 1 sigma of the model")
    for name, (value, sigma) in model.evaluate(t).items():
        print(f"{name:<6} {value:>22.12g} +- {sigma:<10.3g} {model.fits[name].unit}")
    return ExitCode.OK
