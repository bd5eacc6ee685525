"""The `bench` command line: one module per command in this package; this file wires them.

`main()` is the edge of every command: what escapes a command ends here as one line on
stderr and an exit code (see `main`), never as a traceback, except a bug.
"""

from __future__ import annotations

import argparse
import os
import select
import sys

# Only what the edge needs is imported here (no command module: `bench.cli.commands` imports the chosen one when
# argparse reaches its name), so `bench --help` and `--version` load no numpy, scipy, python-can, matplotlib or
# Textual, and `main` installs the stop-signal policy before a command module, numpy or a driver is imported (that
# takes a while on a loaded machine: a signal then must not be lost).
from bench import __version__
from bench.cli.commands import CommandChoice
from bench.cli.edge import ExitCode, FirstSignal, ensure_standard_streams, fail, stop_signals
from bench.errors import BenchError
from drivers.errors import DeviceConfigError, DeviceError

DESCRIPTION = ("IMU calibration on a three-axis turntable. Exit codes (every command): 0 done, 1 a schedule file "
               "failed validation, 2 usage, configuration or I/O error (nothing moved), 3 hardware fault or aborted "
               "(table stopped), 4 finished but a quality check failed, 5 simulated truth missed (check-table), 6 "
               "TABLE STATE UNKNOWN (no stop could be sent or confirmed: stop it at the controller), 130 interrupted "
               "(replay), 141 stdout closed by its reader (e.g. | head).")


def build_parser(*, load_all: bool = False) -> argparse.ArgumentParser:
    """The `bench` parser. The commands are listed from `bench.cli.commands.COMMANDS`; a command's module is
    imported when its name is parsed (after `main` installed the signal policy), or every one now (`load_all`,
    for a caller that walks the whole tree)."""
    parser = argparse.ArgumentParser(prog="bench", description=DESCRIPTION)
    parser.add_argument("--version", action="version", version=f"turntable-bench {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True, action=CommandChoice)
    if load_all:
        assert isinstance(commands, CommandChoice)
        commands.load_all()
    return parser


#: exit code when stdout is closed under us (`bench evaluate | head -3`): 128 + SIGPIPE, what a shell reports
#: for a program SIGPIPE killed, so `set -o pipefail` sees a cut-short output as it does for any other tool
EXIT_BROKEN_PIPE = ExitCode.BROKEN_PIPE


def main(argv: list[str] | None = None) -> int:
    """Run one `bench` command; returns its exit code (`bench.cli.common.ExitCode`).

    The edge of every command:
    - KeyboardInterrupt -> "interrupted", 130; a `BenchError` -> one line, 2; a driver
      error (`DeviceError`) -> one line, 2 for a `DeviceConfigError` (nothing was sent), 3 otherwise;
    - an `OSError` (a file that cannot be read or written, a full disk, ...) -> one line
      `bench COMMAND: FILE: reason`, exit 2 (usage or unreadable input/unwritable output);
    - stdout closed by its reader (`bench evaluate | head -3`: a `BrokenPipeError` on
      stdout, also from the final flush) -> nothing printed, stdout pointed at /dev/null
      so that interpreter shutdown prints no "Exception ignored", exit 141 (128 + SIGPIPE,
      as a shell reports a program SIGPIPE killed). A `BrokenPipeError` that is not on
      stdout (a socket, a FIFO) is an `OSError` like any other;
    - a closed stdin, stdout or stderr (`2>&-`) is /dev/null: nothing is written there, the command works;
    - a stop signal (SIGINT, also when inherited as ignored, SIGTERM, SIGHUP) before the command installs its
      own policy (while the modules load, the configuration is read): nothing has moved; one line, exit 130;
    - anything else is a bug and raises with its traceback.
    """
    ensure_standard_streams()       # a closed stdout or stderr becomes /dev/null: nothing written there, no error
    # first thing: from here on no stop signal is lost (a shell's `bench run ... &` inherits SIGINT ignored)
    first = FirstSignal()
    with stop_signals(first):
        try:
            return _main(argv)
        except KeyboardInterrupt as exc:
            return fail("bench", f"interrupted ({exc or 'Ctrl-C'}) before the command started; nothing moved",
                        ExitCode.INTERRUPTED)


def _main(argv: list[str] | None) -> int:
    command = ""
    try:
        args = build_parser().parse_args(argv)
        command = args.command
        code = _run(args)
        sys.stdout.flush()            # what is still buffered goes out here, where a closed pipe is caught
        return code
    except SystemExit:                # --help, --version, a usage error: their output is flushed here too
        if not _flush_stdout():
            return EXIT_BROKEN_PIPE
        raise
    except BrokenPipeError as exc:
        if _stdout_closed():
            _silence_stdout()
            return EXIT_BROKEN_PIPE
        return _os_error(command, exc)
    except OSError as exc:
        return _os_error(command, exc)


def _run(args: argparse.Namespace) -> int:
    try:
        return int(args.func(args))
    except KeyboardInterrupt as exc:
        return fail(f"bench {args.command}", f"interrupted ({exc or 'Ctrl-C'})", ExitCode.INTERRUPTED)
    except DeviceConfigError as exc:
        # a URL, dialect, option or limit the driver refused before sending anything: nothing moved
        print(f"bench {args.command}: {exc}", file=sys.stderr)
        return ExitCode.USAGE
    except DeviceError as exc:
        # a command that moves hardware handles these itself (and stops the table); this is the backstop.
        # (DeviceTimeout and DeviceConnectionError are OSErrors too: they end here, not as I/O errors.)
        print(f"bench {args.command}: {type(exc).__name__}: {exc}", file=sys.stderr)
        return ExitCode.FAULT
    except BenchError as exc:
        print(f"bench {args.command}: {exc}", file=sys.stderr)
        return ExitCode.USAGE


def _os_error(command: str, exc: OSError) -> int:
    """One line naming the file and the reason; exit 2."""
    prog = f"bench {command}" if command else "bench"
    if exc.filename is not None and exc.strerror:
        files = f"{exc.filename} -> {exc.filename2}" if exc.filename2 is not None else f"{exc.filename}"
        message = f"{files}: {exc.strerror}"
    else:
        message = str(exc) or type(exc).__name__
    print(f"{prog}: {message}", file=sys.stderr)
    return ExitCode.USAGE


def _stdout_closed() -> bool:
    """True if stdout is a pipe or socket its reader has closed (or a flush of it fails with EPIPE)."""
    if not _flush_stdout():
        return True
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):     # not a real file (tests capture it)
        return False
    poller = select.poll()
    poller.register(fd, select.POLLOUT)
    return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))


def _flush_stdout() -> bool:
    """Flush stdout; False (and stdout silenced) if its reader has gone."""
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        _silence_stdout()
        return False
    except (OSError, ValueError):     # closed or not flushable: nothing more to say there
        return True
    return True


def _silence_stdout() -> None:
    """Point stdout's file descriptor at /dev/null: what is still buffered goes nowhere at shutdown."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


if __name__ == "__main__":
    sys.exit(main())
