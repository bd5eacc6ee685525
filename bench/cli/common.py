"""What every `bench` command shares: exit codes, the one-line error, shared options, a live run.

The exit codes are one vocabulary for all commands (documented once, in the README):
a command returns an `ExitCode`, prints at most one line on stderr when it fails, and
lets an exception that is not a `BenchError` or a driver error raise (a bug).
"""

from __future__ import annotations

import argparse
import math
import signal
import sys
from enum import IntEnum
from typing import TYPE_CHECKING

from bench.cli.progress import ProgressPrinter
from bench.errors import BenchError
from bench.model.imu import NoiseModel
from drivers.errors import ImuError, TurntableError

if TYPE_CHECKING:
    from bench.run.runner import BenchRun


class ExitCode(IntEnum):
    """The exit codes of every `bench` command."""

    OK = 0
    #: a schedule file failed validation or cannot be loaded (`bench schedules ...`)
    INVALID_SCHEDULE = 1
    #: usage or configuration error, unreadable input, a demand refused by the limits: nothing moved
    USAGE = 2
    #: hardware fault, lost link or aborted (Ctrl-C, e-stop): the table was commanded to stop
    FAULT = 3
    #: finished, but a quality check failed (the report says which)
    QUALITY = 4
    #: `bench check-table` on the simulator: the estimate misses the simulated truth by more than 3 sigma
    SIM_TRUTH_MISSED = 5
    #: stopped by Ctrl-C where nothing can move (`bench replay`)
    INTERRUPTED = 130


#: errors a command turns into one line and an exit code; anything else is a bug and raises
KNOWN_ERRORS = (BenchError, TurntableError, ImuError)


def fail(prog: str, message: str, code: ExitCode) -> ExitCode:
    """Print `prog: message` on stderr (one line) and return `code` (also when stderr is gone: a closed pipe)."""
    try:
        print(f"{prog}: {message}", file=sys.stderr, flush=True)
    except OSError:
        pass
    return code


def speed_factor(text: str) -> float:
    """argparse type of a `--speed X` option: a positive factor of real time."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive factor of real time, got {text!r}")
    return value


_DEFAULT_NOISE = NoiseModel()


def add_noise_arguments(parser: argparse.ArgumentParser) -> None:
    """The sensor-noise options (`noise_from_args` reads them); defaults are the simulator's."""
    group = parser.add_argument_group("sensor noise (defaults: the simulated IMU's)")
    group.add_argument("--gyro-arw", type=float, default=_DEFAULT_NOISE.gyro_arw_deg_rt_h,
                       help="gyro angle random walk, deg/sqrt(h) (default %(default)g)")
    group.add_argument("--acc-vrw", type=float, default=_DEFAULT_NOISE.acc_vrw_ug_rt_hz,
                       help="accelerometer velocity random walk, ug/sqrt(Hz) (default %(default)g)")
    group.add_argument("--gyro-bi", type=float, default=_DEFAULT_NOISE.gyro_bias_instability_dph,
                       help="gyro bias instability, deg/h (default %(default)g)")
    group.add_argument("--acc-bi", type=float, default=_DEFAULT_NOISE.acc_bias_instability_ug,
                       help="accelerometer bias instability, ug (default %(default)g)")
    group.add_argument("--no-quantise", action="store_true", help="leave count quantisation out of the noise")


def noise_from_args(args: argparse.Namespace) -> NoiseModel:
    """The noise model of the options `add_noise_arguments` added."""
    return NoiseModel(args.gyro_arw, args.gyro_bi, args.acc_vrw, args.acc_bi,
                      _DEFAULT_NOISE.correlation_time_s, not args.no_quantise)


def run_plan(run: BenchRun, prog: str, *, quiet: bool, simulated: bool) -> ExitCode | None:
    """Open `run`'s devices and execute its plan with terminal progress, Ctrl-C aborting it.

    Returns the exit code (after printing one line) when it could not start (USAGE,
    nothing moved) or enable the table (FAULT); None once the plan ran (see
    `run.sequencer` for how it ended)."""
    # Ctrl-C from here on aborts the run, also while the devices open (the run then ends at its start)
    previous_handler = signal.signal(signal.SIGINT, lambda *_: run.abort("interrupted (Ctrl-C)"))
    try:
        try:
            run.open()
        except (TurntableError, ImuError, BenchError, OSError) as exc:
            return fail(prog, f"cannot start: {exc}; nothing moved", ExitCode.USAGE)
        progress = ProgressPrinter(run.plan.steps, quiet=quiet, simulated=simulated)
        run.extra_listeners.append(progress)
        try:
            run.run()
        except TurntableError as exc:
            return fail(prog, f"cannot enable the table: {exc}; nothing moved", ExitCode.FAULT)
        finally:
            progress.close()
    finally:
        signal.signal(signal.SIGINT, previous_handler)
    return None


__all__ = ["KNOWN_ERRORS", "ExitCode", "add_noise_arguments", "fail", "noise_from_args", "run_plan", "speed_factor"]
