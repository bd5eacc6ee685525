"""The edge of every `bench` command, light enough to load before anything else (`bench.cli.main.main` installs
the stop-signal policy with it before importing a command, numpy or a driver): the exit codes, the one-line
failure, and the stop signals.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import signal
import sys
import threading
from enum import IntEnum
from types import FrameType
from typing import Any, Callable, Iterator


class ExitCode(IntEnum):
    """The exit codes of every `bench` command."""

    OK = 0
    #: a schedule file failed validation or cannot be loaded (`bench schedules ...`)
    INVALID_SCHEDULE = 1
    #: usage or configuration error, unreadable input, a demand refused by the limits: nothing moved
    USAGE = 2
    #: hardware fault, lost link or aborted (Ctrl-C, e-stop): the table was commanded to stop
    FAULT = 3
    #: finished, but the verdict is FAIL: a quality check, an acceptance limit or a verification check failed (the
    #: report says which); a verdict NOT CHECKED (no check ran) is OK, not this
    QUALITY = 4
    #: `bench check-table` on the simulator: the estimate misses the simulated truth by more than 3 sigma
    SIM_TRUTH_MISSED = 5
    #: no stop could be sent to the controller or confirmed (its link is gone): the table may still be moving;
    #: the message says TABLE STATE UNKNOWN, the operator must stop it at the controller
    TABLE_STATE_UNKNOWN = 6
    #: the command's files are written but the records database did not take them (unreachable, locked, full, a
    #: newer schema): a failure to record is not a success; `bench db import` records the files later
    NOT_RECORDED = 7
    #: stopped by a signal (SIGINT, SIGTERM, SIGHUP) where nothing can move (`bench replay`)
    INTERRUPTED = 130
    #: stdout closed by its reader (`bench evaluate | head`): a quiet stop, 128 + SIGPIPE
    BROKEN_PIPE = 141


#: The longest line a command prints about one item of its progress (an archive item, a warning); a damaged log's
#: reasons ran to some 2,000 characters, a block that wraps past reading.
LINE_MAX = 400
#: The longest error line (`fail`): longer than a progress line, because an error that lists several reasons
#: (a resumed log's mismatches, a damaged log's chunks) must keep the one the user acts on; it still cuts the
#: pathological ones (thousands of characters) in the middle, where a list repeats itself.
ERROR_LINE_MAX = 1200


def bounded_line(text: str, limit: int = LINE_MAX) -> str:
    """`text` as one line of about `limit` characters at most: its start and its end (where a cause often is),
    saying how much between them is left out."""
    text = " ".join(text.splitlines())
    if len(text) <= limit:
        return text
    head, tail = limit * 2 // 3, limit // 4
    return f"{text[:head]} ... [{len(text) - head - tail} characters left out] ... {text[-tail:]}"


def fail(prog: str, message: str, code: ExitCode) -> ExitCode:
    """Print `prog: message` on stderr (one line, `bounded_line` to `ERROR_LINE_MAX`) and return `code` (also
    when stderr is gone: a closed pipe)."""
    try:
        print(bounded_line(f"{prog}: {message}", ERROR_LINE_MAX), file=sys.stderr, flush=True)
    except OSError:
        pass
    return code


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
            handler = signal.signal(signum, lambda received, frame: _deliver(on_signal, received, frame))
            # (None: a handler not installed from Python; the default is the closest to put back)
            previous[signum] = signal.SIG_DFL if handler is None else handler
        yield
    finally:
        for installed, handler in previous.items():
            signal.signal(installed, handler)


#: how long a stop signal that came during an import waits before it is delivered again (see `_deliver`)
REDELIVER_AFTER_S = 0.005


def _deliver(on_signal: Callable[[int], None], signum: int, frame: FrameType | None) -> None:
    """Call `on_signal(signum)`, unless the signal came while a module was being imported: then send it again to
    the main thread a moment later, until it lands outside an import.

    Why: an exception raised inside an import can come out as another one. numpy's compiled core, interrupted
    while it imports `datetime`, reports an ImportError with a page of advice, so Ctrl-C during start-up ended in
    a traceback instead of "interrupted". Deferred by milliseconds, the signal is never lost."""
    if not _importing(frame):
        on_signal(signum)
        return
    main_thread = threading.main_thread()

    def again() -> None:
        if main_thread.is_alive() and main_thread.ident is not None:
            with contextlib.suppress(ProcessLookupError, OSError):
                signal.pthread_kill(main_thread.ident, signum)

    timer = threading.Timer(REDELIVER_AFTER_S, again)
    timer.daemon = True
    timer.start()


def _importing(frame: FrameType | None) -> bool:
    """True when the interrupted code runs inside an import (importlib's frozen bootstrap is on the stack)."""
    while frame is not None:
        if frame.f_code.co_filename.startswith("<frozen importlib"):
            return True
        frame = frame.f_back
    return False


def ensure_standard_streams() -> None:
    """A closed stdin, stdout or stderr (`bench run ... 2>&-`, `>&-`) is opened on /dev/null: the command writes
    nothing there and keeps working (Python leaves `sys.stderr` None: `.isatty()`, `.flush()` on it were
    AttributeErrors), and no file the command opens later (a run log) can take descriptor 1 or 2. A descriptor 1
    or 2 open for reading only is a closed one too: a launcher's file leaked into the hole (a pyenv shim's script
    is fd 2 under `2>&-`), where every write would fail."""
    for fd, name in enumerate(("stdin", "stdout", "stderr")):
        if not _usable(fd):         # /dev/null takes its number
            devnull = os.open(os.devnull, os.O_RDONLY if fd == 0 else os.O_WRONLY)
            if devnull != fd:
                os.dup2(devnull, fd)
                os.close(devnull)
        if getattr(sys, name) is None:
            setattr(sys, name, open(fd, "r" if fd == 0 else "w", closefd=False, encoding="utf-8",
                                    errors="backslashreplace"))


def _usable(fd: int) -> bool:
    """Open, and for stdout and stderr open for writing."""
    try:
        access = fcntl.fcntl(fd, fcntl.F_GETFL) & os.O_ACCMODE
    except OSError:
        return False
    return fd == 0 or access in (os.O_WRONLY, os.O_RDWR)


class FirstSignal:
    """A stop-signal handler that raises `Interrupted` for the first signal only: the ones after it, while the
    command is already ending (printing its line, closing), change nothing and print no traceback."""

    def __init__(self) -> None:
        self.signum: int | None = None

    def __call__(self, signum: int) -> None:
        if self.signum is None:
            self.signum = signum
            raise Interrupted(signum)


__all__ = ["ERROR_LINE_MAX", "LINE_MAX", "STOP_SIGNALS", "ExitCode", "FirstSignal", "Interrupted", "bounded_line",
           "ensure_standard_streams", "fail",
           "raise_interrupted", "signal_name", "stop_signals"]
