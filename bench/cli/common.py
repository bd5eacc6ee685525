"""What every `bench` command shares: exit codes, the one-line error, shared options, a live run.

The exit codes are one vocabulary for all commands (documented once, in the README):
a command returns an `ExitCode`, prints at most one line on stderr when it fails, and
lets an exception that is not a `BenchError` or a driver error raise (a bug).
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import TYPE_CHECKING, Any, Callable

from bench.cli.edge import STOP_SIGNALS, ExitCode, Interrupted, fail, raise_interrupted, signal_name, stop_signals
from bench.cli.progress import ProgressPrinter
from bench.errors import BenchError
from bench.model.imu import NoiseModel
from drivers.errors import DeviceError, TurntableProtocolError, TurntableTimeout
from drivers.turntable import DIALECTS
from drivers.turntable.base import TABLE_STATE_UNKNOWN

if TYPE_CHECKING:
    from bench.run.runner import BenchRun
    from bench.run.sequencer import Sequencer
    from drivers.session import DeviceSession


def ended_early(prog: str, what: str, sequencer: Sequencer | None, after: str = "") -> ExitCode:
    """The one line of a run that ended early: "`what`; table stopped`after`", exit 3, or, when its stop could
    not be sent or confirmed, "`what`; TABLE STATE UNKNOWN: ...`after`", exit 6 (`ExitCode.TABLE_STATE_UNKNOWN`)."""
    if sequencer is not None and sequencer.stop_result is not None and sequencer.stop_result.unknown:
        return fail(prog, f"{what}; {sequencer.stop_words}{after}", ExitCode.TABLE_STATE_UNKNOWN)
    return fail(prog, f"{what}; table stopped{after}", ExitCode.FAULT)


def number_type(rule: str, accept: Callable[[float], bool]) -> Callable[[str], float]:
    """An argparse type: a finite number that `accept`s, else "not a number: ..." or "must be `rule`, got ..."."""
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not (math.isfinite(value) and accept(value)):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text!r}")
        return value

    return parse


#: argparse type of a `--speed X` option: a positive factor of real time
speed_factor = number_type("a positive factor of real time", lambda value: value > 0)


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


def add_scheduler_arguments(parser: argparse.ArgumentParser | argparse._ArgumentGroup, *, default: str,
                            what: str, note: str = "", after: str = "") -> None:
    """`--scheduler` and `--workers`: where `bench.parallel.run_tasks` runs `what` (checked there)."""
    parser.add_argument("--scheduler", default=default, metavar="local|loop|tcp://HOST:PORT",
                        help=f"{note}where {what}: 'loop' one by one in "
                             "this process without Dask, 'local' on a Dask cluster started on this machine, "
                             "tcp://HOST:PORT on a running Dask scheduler (pip install -e '.[archive]'); "
                             f"default %(default)s{after}")
    parser.add_argument("--workers", type=int, metavar="N",
                        help=f"{note}with --scheduler local: worker processes (default: the machine's cores)")


def task_progress(what: str, stream: Any = None) -> Callable[[int, int], None] | None:
    """A `progress(done, total)` for `bench.parallel` tasks: a line redrawn in place on a terminal, None elsewhere
    (logs and pipes get the result only)."""
    out = stream if stream is not None else sys.stderr
    if not out.isatty():
        return None

    def progress(done: int, total: int) -> None:
        out.write(f"\r{what}: {done}/{total}" + ("\n" if done == total else ""))
        out.flush()
    return progress


def drive_device(prog: str, device: DeviceSession[Any], command: Callable[[], ExitCode], *, errors: type[Exception],
                 refused: tuple[type[Exception], ...], unreachable: str, make_safe: Callable[[], str],
                 note_faults: bool = True, refused_at_connect: tuple[type[Exception], ...] = (),
                 hint: Callable[[Exception], str] = lambda exc: "") -> ExitCode:
    """Connect `device` (an `errors` error: "`unreachable`: why", exit 2 like any device that cannot be reached
    before anything was commanded; a `refused_at_connect` one, limits the device refuses: exit 2, nothing sent),
    run `command` with SIGTERM and SIGHUP ending it like Ctrl-C, and close the device however it ends. A `refused`
    error (a demand beyond the limits) is exit 2, nothing sent; another `errors` error or a stop signal makes the
    device safe (`make_safe`, which says what it did: the line ends with it; after an error only with
    `note_faults`) and is exit 3. `hint(error)`: what to check, added to an error's line when not empty."""
    def explained(text: str, exc: Exception) -> str:
        advice = hint(exc)
        return f"{text} ({advice})" if advice else text

    try:
        device.connect()
    except refused_at_connect as exc:      # a driver that checks the limits against the device's (acutrol)
        return fail(prog, f"refused, nothing sent: {exc}", ExitCode.USAGE)
    except errors as exc:
        return fail(prog, explained(f"{unreachable}: {exc}", exc) + "; nothing sent", ExitCode.USAGE)
    try:
        # SIGTERM and SIGHUP end the command like Ctrl-C (an `Interrupted`, a KeyboardInterrupt)
        with stop_signals(raise_interrupted):
            return command()
    except refused as exc:
        return fail(prog, f"refused, nothing sent: {exc}", ExitCode.USAGE)
    except errors as exc:
        done = _safely(make_safe)
        return fail(prog, explained(f"{type(exc).__name__}: {exc}", exc)
                    + (f"; {done}" if note_faults or _unknown(done) else ""), _made_safe_code(done))
    except KeyboardInterrupt as exc:
        done = _safely(make_safe)
        return fail(prog, f"interrupted ({exc or 'Ctrl-C'}); {done}", _made_safe_code(done))
    finally:
        device.close()


def dialect_hint(exc: Exception, dialect: str, option: str) -> str:
    """What to check when a turntable controller gave no reply or replies `dialect` cannot read before it ever
    answered: that is what a controller speaking another dialect gives ("" for any other error). `option`: where
    the dialect is set (`--dialect`, `[table] dialect`)."""
    if not isinstance(exc, (TurntableTimeout, TurntableProtocolError)):
        return ""
    if dialect == "modbus":
        return ("check the controller's unit id, serial settings and register map: a Modbus RTU device silently "
                "ignores another unit id")
    others = ", ".join(d for d in sorted(DIALECTS) if d != dialect)
    return (f"check {option}: a controller speaking another dialect ({others}) gives no reply or replies "
            f"{dialect} cannot read")


def _unknown(done: str) -> bool:
    return TABLE_STATE_UNKNOWN in done


def _made_safe_code(done: str) -> ExitCode:
    """Exit 3 after a stop that was sent; 6 when `make_safe` says the table state is unknown."""
    return ExitCode.TABLE_STATE_UNKNOWN if _unknown(done) else ExitCode.FAULT


def _safely(make_safe: Callable[[], str]) -> str:
    """`make_safe()`, which a second stop signal cannot cut short (it is bounded by the driver's timeouts and
    retries)."""
    with stop_signals(lambda _signum: None):
        return make_safe()


def run_plan(run: BenchRun, prog: str, *, quiet: bool, simulated: bool) -> ExitCode | None:
    """Open `run`'s devices and execute its plan with terminal progress; a stop signal aborts it.

    SIGINT (Ctrl-C), SIGTERM and SIGHUP (`stop_signals`) abort the run from here on, also while the
    devices open (the run then ends at its start): the table is stopped, servos off, the log kept.
    A signal that comes after the plan's last check (the run is complete) is not lost: it is raised here as
    `Interrupted` once the plan has ended, for the caller to end as interrupted.
    Returns the exit code (after printing one line) when it could not start (USAGE,
    nothing moved) or enable the table (FAULT); None once the plan ran (see
    `run.sequencer` for how it ended)."""
    received: list[int] = []

    def abort(signum: int) -> None:
        received.append(signum)
        run.abort(f"interrupted ({signal_name(signum)})")

    with stop_signals(abort):
        dialect = run.config.table.dialect
        option = f'[table] dialect = "{dialect}"'
        try:
            run.open()
        except (DeviceError, BenchError, OSError) as exc:
            advice = dialect_hint(exc, dialect, option)
            return fail(prog, f"cannot start: {exc}{f' ({advice})' if advice else ''}; nothing moved",
                        ExitCode.USAGE)
        # the progress goes by what the run will take (its controller's timing), not the plan's recorded estimates
        from bench.run.timing import estimates
        progress = ProgressPrinter(run.plan.steps, quiet=quiet, simulated=simulated,
                                   estimates=estimates(run.config, run.plan.steps, simulated))
        run.extra_listeners.append(progress)
        try:
            run.run()
        except DeviceError as exc:      # the table's first exchange may be here (a driver that connects silently)
            advice = dialect_hint(exc, dialect, option)
            return fail(prog, f"cannot enable the table: {exc}{f' ({advice})' if advice else ''}; nothing moved",
                        ExitCode.FAULT)
        finally:
            progress.close()
    if received and run.sequencer is not None and run.sequencer.error is None:
        raise Interrupted(received[0])      # the plan completed under the signal: the run ends as interrupted
    return None


__all__ = ["STOP_SIGNALS", "ExitCode", "Interrupted", "add_noise_arguments", "dialect_hint",
           "drive_device",
           "ended_early", "fail",
           "noise_from_args", "raise_interrupted", "run_plan", "signal_name", "speed_factor", "stop_signals"]
