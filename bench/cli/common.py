"""What every `bench` command shares: exit codes, the one-line error, shared options, a live run.

The exit codes are one vocabulary for all commands (documented once, in the README):
a command returns an `ExitCode`, prints at most one line on stderr when it fails, and
lets an exception that is not a `BenchError` or a driver error raise (a bug).
"""

from __future__ import annotations

import argparse
import contextlib
import math
import signal
import sys
import threading
from enum import IntEnum
from types import FrameType
from typing import TYPE_CHECKING, Any, Callable, Iterator

from bench.cli.progress import ProgressPrinter
from bench.errors import BenchError
from bench.model.imu import NoiseModel
from drivers.errors import ChamberError, ImuError, TurntableError
from drivers.turntable.base import TABLE_STATE_UNKNOWN

if TYPE_CHECKING:
    from bench.run.runner import BenchRun
    from bench.run.sequencer import Sequencer
    from drivers.session import DeviceSession


class ExitCode(IntEnum):
    """The exit codes of every `bench` command."""

    OK = 0
    #: a schedule file failed validation or cannot be loaded (`bench schedules ...`)
    INVALID_SCHEDULE = 1
    #: usage or configuration error, unreadable input, a demand refused by the limits: nothing moved
    USAGE = 2
    #: hardware fault, lost link or aborted (Ctrl-C, e-stop): the table was commanded to stop
    FAULT = 3
    #: finished, but a quality check failed or the acceptance verdict is fail (the report says which)
    QUALITY = 4
    #: `bench check-table` on the simulator: the estimate misses the simulated truth by more than 3 sigma
    SIM_TRUTH_MISSED = 5
    #: no stop could be sent to the controller or confirmed (its link is gone): the table may still be moving;
    #: the message says TABLE STATE UNKNOWN, the operator must stop it at the controller
    TABLE_STATE_UNKNOWN = 6
    #: stopped by a signal (SIGINT, SIGTERM, SIGHUP) where nothing can move (`bench replay`)
    INTERRUPTED = 130
    #: stdout closed by its reader (`bench evaluate | head`): a quiet stop, 128 + SIGPIPE
    BROKEN_PIPE = 141


#: errors a command turns into one line and an exit code; anything else is a bug and raises
KNOWN_ERRORS = (BenchError, TurntableError, ImuError)


def fail(prog: str, message: str, code: ExitCode) -> ExitCode:
    """Print `prog: message` on stderr (one line) and return `code` (also when stderr is gone: a closed pipe)."""
    try:
        print(f"{prog}: {message}", file=sys.stderr, flush=True)
    except OSError:
        pass
    return code


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


#: The signals that end a command the way Ctrl-C does: SIGINT (Ctrl-C), SIGTERM (kill, systemd, a CI job
#: cancelled) and SIGHUP (the terminal or SSH session went away).
STOP_SIGNALS: tuple[signal.Signals, ...] = tuple(
    getattr(signal, name) for name in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, name))


def signal_name(signum: int) -> str:
    """How a message names a stop signal: "Ctrl-C" for SIGINT, else the signal's name."""
    return "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name


class Interrupted(KeyboardInterrupt):
    """A stop signal (`STOP_SIGNALS`) raised where the command is (`raise_interrupted`), like Ctrl-C.

    A KeyboardInterrupt, so that whatever handles Ctrl-C handles SIGTERM and SIGHUP alike."""

    def __init__(self, signum: int):
        super().__init__(signal_name(signum))
        self.signum = signum


def raise_interrupted(signum: int) -> None:
    """A `stop_signals` handler: end the command where it is, as Ctrl-C does (see `Interrupted`)."""
    raise Interrupted(signum)


@contextlib.contextmanager
def stop_signals(on_signal: Callable[[int], None]) -> Iterator[None]:
    """While the block runs, SIGINT, SIGTERM and SIGHUP call `on_signal(signum)`; the previous handlers
    come back when it ends. Only in the main thread (elsewhere Python cannot install handlers: nothing is).

    SIGINT and SIGTERM are caught even when ignored (a shell starts `bench ... &` with SIGINT ignored);
    an ignored SIGHUP stays ignored (`nohup bench run ...` asks for exactly that)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous: dict[int, Callable[[int, FrameType | None], Any] | int] = {}
    try:
        for signum in STOP_SIGNALS:
            if signum == getattr(signal, "SIGHUP", None) and signal.getsignal(signum) is signal.SIG_IGN:
                continue
            handler = signal.signal(signum, lambda received, _frame: on_signal(received))
            # (None: a handler not installed from Python; the default is the closest to put back)
            previous[signum] = signal.SIG_DFL if handler is None else handler
        yield
    finally:
        for installed, handler in previous.items():
            signal.signal(installed, handler)


def drive_device(prog: str, device: DeviceSession[Any], command: Callable[[], ExitCode], *, errors: type[Exception],
                 refused: tuple[type[Exception], ...], unreachable: str, make_safe: Callable[[], str],
                 note_faults: bool = True) -> ExitCode:
    """Connect `device` (an `errors` error: "`unreachable`: why", exit 3), run `command` with SIGTERM and SIGHUP
    ending it like Ctrl-C, and close the device however it ends. A `refused` error (a demand beyond the limits)
    is exit 2, nothing sent; another `errors` error or a stop signal makes the device safe (`make_safe`, which
    says what it did: the line ends with it; after an error only with `note_faults`) and is exit 3."""
    try:
        device.connect()
    except errors as exc:
        return fail(prog, f"{unreachable}: {exc}", ExitCode.FAULT)
    try:
        # SIGTERM and SIGHUP end the command like Ctrl-C (an `Interrupted`, a KeyboardInterrupt)
        with stop_signals(raise_interrupted):
            return command()
    except refused as exc:
        return fail(prog, f"refused, nothing sent: {exc}", ExitCode.USAGE)
    except errors as exc:
        done = _safely(make_safe)
        return fail(prog, f"{type(exc).__name__}: {exc}" + (f"; {done}" if note_faults or _unknown(done) else ""),
                    _made_safe_code(done))
    except KeyboardInterrupt as exc:
        done = _safely(make_safe)
        return fail(prog, f"interrupted ({exc or 'Ctrl-C'}); {done}", _made_safe_code(done))
    finally:
        device.close()


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
    Returns the exit code (after printing one line) when it could not start (USAGE,
    nothing moved) or enable the table (FAULT); None once the plan ran (see
    `run.sequencer` for how it ended)."""
    with stop_signals(lambda signum: run.abort(f"interrupted ({signal_name(signum)})")):
        try:
            run.open()
        except (TurntableError, ImuError, ChamberError, BenchError, OSError) as exc:
            return fail(prog, f"cannot start: {exc}; nothing moved", ExitCode.USAGE)
        progress = ProgressPrinter(run.plan.steps, quiet=quiet, simulated=simulated)
        run.extra_listeners.append(progress)
        try:
            run.run()
        except TurntableError as exc:
            return fail(prog, f"cannot enable the table: {exc}; nothing moved", ExitCode.FAULT)
        finally:
            progress.close()
    return None


__all__ = ["KNOWN_ERRORS", "STOP_SIGNALS", "ExitCode", "Interrupted", "add_noise_arguments", "drive_device",
           "ended_early", "fail",
           "noise_from_args", "raise_interrupted", "run_plan", "signal_name", "speed_factor", "stop_signals"]
