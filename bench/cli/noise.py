"""`bench noise`: Allan deviation and noise terms of a static recording (logic in `bench.noise`).

`bench noise LOG` analyses the longest dwell of a run log (a `static-noise` run);
`bench noise --sim` the simulated IMU alone. Writes `<name>.noise.json`, `.noise.md` and
`.noise.html`. Exit codes: 0 done, 2 usage error or a log that cannot be used.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from pathlib import Path

from bench.cli.common import ExitCode, add_noise_arguments, fail, noise_from_args, number_type
from bench.errors import InputError
from bench.files import OutputFileError, make_output_folder
from bench.model.imu import default_sim_imu
from bench.model.result import CalibrationResult, ResultFormatError

PROG = "bench noise"
MAX_SIM_SAMPLES = 100_000_000     # per channel: 6 channels of float64 are 4.8 GB


_positive = number_type("a positive number", lambda value: value > 0)


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "noise",
        description="Overlapping Allan deviation of each gyro and accelerometer with +-1 sigma intervals and the "
                    "fitted noise terms (IEEE Std 952): of the longest dwell of a run log (record one with "
                    "plan.positions = \"static-noise\"), or of the simulated IMU alone (--sim). Writes "
                    "NAME.noise.json, .noise.md and .noise.html. Exit codes: 0 done, 2 usage error or a log "
                    "that cannot be used.")
    parser.add_argument("log", nargs="?", metavar="LOG", help="run log (.mcap) holding a static dwell")
    parser.add_argument("--sim", action="store_true", help="analyse the simulated IMU alone (no table motion)")
    parser.add_argument("--duration-h", type=_positive, default=1.0, help="--sim: hours recorded (default 1)")
    parser.add_argument("--rate-hz", type=_positive, default=200.0, help="--sim: sample rate, Hz (default 200)")
    parser.add_argument("--seed", type=int, default=0, help="--sim: random seed (default 0)")
    parser.add_argument("--gyro-rrw", type=float, default=0.0,
                        help="--sim: gyro rate random walk, deg/h/sqrt(h) (default 0)")
    parser.add_argument("--acc-rrw", type=float, default=0.0,
                        help="--sim: accelerometer bias random walk, ug/sqrt(h) (default 0)")
    parser.add_argument("--correlation-time-s", type=_positive, default=None,
                        help="--sim: bias instability (Gauss-Markov) correlation time, s (default the simulator's)")
    add_noise_arguments(parser)
    parser.add_argument("--calibration", metavar="RESULT.json",
                        help="scale factors (Kg, Ka) from a calibration result (needed for a hardware log)")
    parser.add_argument("--points-per-octave", type=int, default=1, metavar="N",
                        help="cluster times per octave (default 1: octave-spaced)")
    parser.add_argument("--out", metavar="DIR", help="output folder (default: next to the log; runs/ with --sim)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.set_defaults(func=cmd_noise)


def _sim_noise(args: argparse.Namespace):
    noise = dataclasses.replace(noise_from_args(args), gyro_rrw_dph_rt_h=args.gyro_rrw, acc_rrw_ug_rt_h=args.acc_rrw)
    if args.correlation_time_s is not None:
        noise = dataclasses.replace(noise, correlation_time_s=args.correlation_time_s)
    return noise


def cmd_noise(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy, python-can, mcap, matplotlib): imported when the command runs, not for its --help
    from bench.log.reader import LogError
    from bench.noise.allan import AllanError
    from bench.noise.from_log import NoiseInputError, analyse_log
    from bench.report.noise import write_noise_outputs

    if args.sim == bool(args.log):
        return fail(PROG, "give a LOG or --sim (not both)", ExitCode.USAGE)
    if not 1 <= args.points_per_octave <= 64:
        return fail(PROG, f"--points-per-octave must be 1..64, got {args.points_per_octave}", ExitCode.USAGE)
    levels = {"--gyro-arw": args.gyro_arw, "--acc-vrw": args.acc_vrw, "--gyro-bi": args.gyro_bi,
              "--acc-bi": args.acc_bi, "--gyro-rrw": args.gyro_rrw, "--acc-rrw": args.acc_rrw}
    for option, value in levels.items():
        if not (math.isfinite(value) and value >= 0):
            return fail(PROG, f"{option} must be a finite number >= 0, got {value}", ExitCode.USAGE)
    try:
        if args.sim:
            n = args.duration_h * 3600.0 * args.rate_hz
            if n > MAX_SIM_SAMPLES:
                return fail(PROG, f"--duration-h x --rate-hz gives {n:.3g} samples per channel, more than "
                                  f"{MAX_SIM_SAMPLES:,}", ExitCode.USAGE)
            if not 0 <= args.seed < 2 ** 32:
                return fail(PROG, f"--seed must be 0..4294967295, got {args.seed}", ExitCode.USAGE)
            result, name = _simulated(args)
            out_dir = Path(args.out or "runs")
        else:
            calibration, label = None, ""
            if args.calibration:
                try:
                    calibration = CalibrationResult.load(args.calibration).imu_coefficients()
                except OSError as exc:
                    return fail(PROG, f"{args.calibration}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
                except (ResultFormatError, KeyError) as exc:
                    return fail(PROG, f"{args.calibration}: not a usable calibration result: {exc}", ExitCode.USAGE)
                except InputError as exc:   # not a regular file, too large
                    return fail(PROG, str(exc), ExitCode.USAGE)
                label = Path(args.calibration).name
            result, name = analyse_log(args.log, calibration=calibration, calibration_label=label,
                                       points_per_octave=args.points_per_octave)
            out_dir = Path(args.out) if args.out else Path(args.log).parent
    except (LogError, NoiseInputError, AllanError) as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    try:
        paths = write_noise_outputs(result, make_output_folder(out_dir), name)
    except OutputFileError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"cannot write the result: {exc.strerror or exc} ({exc.filename or out_dir})",
                    ExitCode.USAGE)
    if not args.quiet:
        print(_summary(result))
        print("result: " + "\n        ".join(str(p) for p in paths))
    return ExitCode.OK


def _simulated(args: argparse.Namespace):
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.model.noise_result import NoiseResult
    from bench.noise.result import analyse
    from bench.noise.simulate import sim_truth, simulate_static

    noise = _sim_noise(args)
    duration_s = args.duration_h * 3600.0
    data = simulate_static(noise, duration_s=duration_s, rate_hz=args.rate_hz, seed=args.seed)
    channels = analyse(data, args.rate_hz, points_per_octave=args.points_per_octave)
    truth = sim_truth(noise, default_sim_imu(), len(data), args.rate_hz, args.points_per_octave)
    source = {"kind": "sim", "seed": args.seed, "duration_h": args.duration_h}
    result = NoiseResult.from_channels(channels, args.rate_hz, len(data), points_per_octave=args.points_per_octave,
                                       source=source, sim_truth=truth)
    return result, f"sim-{args.duration_h:g}h-{args.rate_hz:g}hz-seed{args.seed}"


def _summary(result) -> str:
    truth = (result.sim_truth or {}).get("channels", {})
    lines = []
    for name, ch in result.channels.items():
        cells = []
        for term, t in ch["terms"].items():
            if term == "quantisation":
                continue
            text = f"{term} {t['value']:.4g} +- {t['sigma']:.2g} {t['unit']}" + (" (upper bound)"
                                                                                  if t.get("upper_bound") else "")
            true = truth.get(name, {}).get(term)
            if true:
                text += f" [sim {true:.4g}]"
            cells.append(text)
        cells += [f"{term} not given ({why})" for term, why in (ch.get("terms_not_resolved") or {}).items()
                  if term != "quantisation"]
        lines.append(f"{name}: " + "; ".join(cells))
    return "\n".join(lines)


__all__ = ["cmd_noise", "register"]
