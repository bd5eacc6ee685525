"""`bench export`: a result's compensation in the form firmware uses (logic in `bench.calibration.export`),
or a thermal model's polynomials (`thermal.json` from `bench thermal`; logic in `bench.thermal.export`).

Exit codes: 0 written; 2 usage error, a result that cannot be read or lacks coefficients,
an output that cannot be written.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench.calibration.compensation import compensation_of, load_result
from bench.calibration.export import FORMAT_NAMES, KalibrNoise, export_text, kalibr_noise
from bench.cli.common import ExitCode, fail
from bench.errors import InputError
from bench.files import write_output_text
from bench.model.noise_result import NoiseResult

PROG = "bench export"
#: file suffix -> format, when --format is not given
SUFFIXES = {".json": "json", ".csv": "csv", ".h": "c", ".yaml": "yaml", ".yml": "yaml", ".toml": "toml"}
#: What each format is, for the line that says what was written.
FORMAT_LABELS = {"json": "JSON", "csv": "CSV", "c": "C header", "yaml": "kalibr IMU YAML", "toml": "TOML"}


def register(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "export",
        description="Write the compensation of a calibration result, u = C (y - b) per triad (C the inverse of "
                    "scale x direction cosines in rad/s or m/s^2 per counts/s, b the bias in counts/s), with "
                    "its 1-sigma uncertainties, as JSON, CSV, a C header, an IMU file for kalibr (YAML, with the "
                    "noise terms of --noise) or TOML; of a thermal model, every coefficient's polynomial in "
                    "temperature with its covariance. Exit codes: 0 written, 2 usage error, unreadable result or "
                    "unwritable output.")
    parser.add_argument("result", metavar="RESULT", help="a result file (<run-id>.result.json) or a thermal model "
                                                          "(thermal.json from `bench thermal`)")
    parser.add_argument("--format", choices=FORMAT_NAMES,
                        help="json, csv, c (a C header), yaml (an IMU file for kalibr) or toml "
                             "(default: from --out's suffix)")
    parser.add_argument("--noise", metavar="NOISE.json",
                        help="yaml: the IMU's noise terms for kalibr, a `bench noise` result (NAME.noise.json)")
    parser.add_argument("--rostopic", default="/imu0", help="yaml: the IMU's ROS topic kalibr reads (default /imu0)")
    parser.add_argument("--out", metavar="FILE", required=True, help="the file to write ('-' for stdout)")
    parser.set_defaults(func=cmd_export)


def cmd_export(args: argparse.Namespace) -> ExitCode:
    # heavy (scipy): imported when the command runs, not for its --help
    from bench.thermal.export import export_thermal
    from bench.thermal.model import ThermalModel, is_thermal_text, read_bounded_text

    fmt = args.format or SUFFIXES.get(Path(args.out).suffix.lower())
    if fmt is None:
        return fail(PROG, f"say --format ({', '.join(FORMAT_NAMES)}): {args.out!r} has no known suffix",
                    ExitCode.USAGE)
    try:
        if is_thermal_text(read_bounded_text(args.result)):    # a thermal model (`bench thermal`)
            text = export_thermal(ThermalModel.load(args.result), fmt)
        else:
            compensation = compensation_of(load_result(args.result))
            text = export_text(compensation, fmt, _noise(args.noise) if fmt == "yaml" else None, args.rostopic)
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{exc.filename or args.result}: cannot read: {exc.strerror or exc}", ExitCode.USAGE)
    if args.out == "-":
        sys.stdout.write(text)
        return ExitCode.OK
    try:
        write_output_text(args.out, text, tuple(p for p in (args.result, args.noise) if p))
    except InputError as exc:
        return fail(PROG, str(exc), ExitCode.USAGE)
    except OSError as exc:
        return fail(PROG, f"{args.out}: cannot write: {exc.strerror or exc}", ExitCode.USAGE)
    print(f"wrote {args.out} ({FORMAT_LABELS.get(fmt, fmt)}, {len(text.encode())} bytes)")
    return ExitCode.OK


def _noise(path: str | None) -> KalibrNoise | None:
    """kalibr's noise terms from a `bench noise` result (None without --noise: export_text says what lacks)."""
    return None if path is None else kalibr_noise(NoiseResult.load(path), Path(path).name)
