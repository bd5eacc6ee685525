"""What the `bench sim ...` commands share: --listen addresses (loopback or not), the refusal of a remote
one without --allow-remote, the fault console's common commands, and serving until a stop."""

from __future__ import annotations

import argparse
import ipaddress
import signal
import sys
import threading
from typing import Any, Callable
from urllib.parse import urlsplit

from bench.cli.common import ExitCode, fail, number_type, raise_interrupted, stop_signals
from bench.errors import InputError

#: the simulators' default idle timeout (`bench.sim.serve.IDLE_TIMEOUT_S`; not imported: `bench` starts without them)
IDLE_TIMEOUT_S = 300.0


def add_idle_timeout_option(parser: argparse.ArgumentParser) -> None:
    """`--idle-timeout-s S`: a TCP connection silent for S seconds is closed (and when every connection slot is
    taken, a new client closes the longest idle one)."""
    parser.add_argument("--idle-timeout-s", type=number_type("a positive number of seconds", lambda v: v > 0),
                        default=IDLE_TIMEOUT_S, metavar="S",
                        help="close a TCP connection that sends nothing for S seconds (default %(default)g); when "
                             "every connection slot is taken a new client closes the longest idle one")


def is_loopback(host: str) -> bool:
    """True for a loopback address literal (127.0.0.0/8, ::1) or `localhost`; any other name counts as remote."""
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def remote_hosts(listen: list[str]) -> list[str]:
    """The --listen addresses that bind beyond loopback (`pty` and malformed ones are left to the listener)."""
    remote = []
    for where in listen:
        if where == "pty":
            continue
        try:
            host = urlsplit(where).hostname
        except ValueError:
            continue
        if host and not is_loopback(host):
            remote.append(where)
    return remote


def refuse_remote(prog: str, remote: list[str]) -> ExitCode:
    """The one line (and exit code) for a --listen address beyond loopback without --allow-remote."""
    return fail(prog, f"{remote[0]} is reachable from the network, not only from this machine; add "
                      "--allow-remote to serve it there, or listen on 127.0.0.1", ExitCode.USAGE)


def host_port(where: str, scheme: str, expected: str) -> tuple[str, int]:
    """(host, port) of a --listen address of `scheme`; InputError saying what is `expected` otherwise."""
    try:
        parts = urlsplit(where)
        host, port = parts.hostname, parts.port
    except ValueError as exc:                   # a port out of range or not a number, a broken [IPv6]
        raise InputError(f"{expected}, not {where!r} ({exc})") from exc
    if parts.scheme != scheme or port is None or not host:
        raise InputError(f"{expected}, not {where!r}")
    return host, port


def apply_console_line(line: str, faults: Any, device_command: Callable[[str, list[str]], str | None],
                       help_text: str, describe_state: Callable[[], str]) -> str:
    """One fault-console line: `device_command(cmd, words)` first (None: not one of the device's; a text to
    print, "" for "ok"), then the wire faults on `faults` (a `WireFaults`), `state` and `help`. Returns what
    to print; a typo is an error line, never an exception (it must not stop the simulator)."""
    # heavy (scipy): the simulators load only when one is served
    from bench.sim.controller import WIRE_FAULTS

    words = line.split()
    if not words:
        return ""
    cmd, rest = words[0].lower(), words[1:]
    try:
        reply = device_command(cmd, rest)
        if reply is not None:
            return reply or "ok"
        if cmd in WIRE_FAULTS:
            count = int(rest[0]) if rest else 1
            if cmd == "exception" and len(rest) > 1:
                faults.exception_code = int(rest[1])
            setattr(faults, cmd, count)
        elif cmd == "state":
            return describe_state()
        elif cmd == "help":
            return help_text
        else:
            return f"unknown command {cmd!r}; type help"
    except Exception as exc:  # noqa: BLE001 - a console typo must not stop the simulator
        return f"error: {exc}"
    return "ok"


def run_console(console: Callable[[str], str]) -> None:
    """The fault console: each stdin line to `console`, its reply printed; on EOF keep serving until a stop
    (this never returns: a stop signal's KeyboardInterrupt ends it)."""
    print("Ctrl-C stops; type 'help' for the fault console", flush=True)
    for line in sys.stdin:
        reply = console(line)
        if reply:
            print(reply, flush=True)
    threading.Event().wait()


def serve_until_stopped(prog: str, device: str, dialect: str, listen: Callable[[str], str], wheres: list[str],
                        remote: list[str], console: Callable[[str], str], closers: list[Callable[[], None]], *,
                        usage_errors: tuple[type[Exception], ...] = (InputError, OSError)) -> ExitCode:
    """Start a listener per --listen address (`listen(where)` returns its URL) and announce it ("simulated
    `device` (`dialect`) listening on URL", a loud warning for the `remote` ones), then run the fault console
    (`console`) until a stop, as `run_until_stopped` says."""
    def serve() -> None:
        for where in wheres:
            url = listen(where)
            print(f"simulated {device} ({dialect}) listening on {url}", flush=True)
            if where in remote:
                print(f"WARNING: {prog}: {url} is reachable from the NETWORK (--allow-remote): anyone who can "
                      f"reach this machine can command the simulated {device}; there is no authentication",
                      file=sys.stderr, flush=True)
        run_console(console)

    return run_until_stopped(prog, serve, closers, usage_errors=usage_errors)


def run_until_stopped(prog: str, serve: Callable[[], None], closers: list[Callable[[], None]], *,
                      usage_errors: tuple[type[Exception], ...]) -> ExitCode:
    """Run `serve` (which starts the simulators, filling `closers`, and serves) until Ctrl-C, SIGTERM or SIGHUP:
    exit 0, "stopped". A `usage_errors` error is one line and exit
    2. `closers` run in reverse however it ends; one that fails is reported and the rest still run."""
    # Ctrl-C (SIGINT) stops the server even when it was started with SIGINT ignored, as a
    # shell does for `bench sim ... &` in a script.
    previous_handler = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with stop_signals(raise_interrupted):
            serve()
    except usage_errors as exc:
        return fail(prog, f"{exc}", ExitCode.USAGE)
    except KeyboardInterrupt:
        return fail(prog, "stopped", ExitCode.OK)
    finally:
        signal.signal(signal.SIGINT, previous_handler)
        for close in reversed(closers):
            try:
                close()
            except Exception as exc:  # noqa: BLE001 - report what failed to close, close the rest
                print(f"{prog}: while closing: {type(exc).__name__}: {exc}", file=sys.stderr)
    return ExitCode.OK


__all__ = ["apply_console_line", "host_port", "is_loopback", "refuse_remote", "remote_hosts", "run_console",
           "run_until_stopped", "serve_until_stopped"]
