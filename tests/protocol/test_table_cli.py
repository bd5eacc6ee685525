"""`bench sim table` served in a subprocess, driven by `bench table` (the real drivers over loopback/pty)."""

from __future__ import annotations

import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time

import pytest

from bench.cli.main import main
from drivers.turntable import open_turntable
from tests.helpers.run import stop_process, wait_for

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _read_line(proc: subprocess.Popen, timeout_s: float = 20.0) -> str:
    """One stdout line of the simulator within a bounded time (lines come from a reader thread)."""
    try:
        return proc.lines.get(timeout=timeout_s)
    except queue.Empty:
        proc.kill()
        pytest.fail("simulator printed nothing in time")


@pytest.fixture
def simulator(request):
    """Start `bench sim table` with the given (dialect, listen); yields (proc, address)."""
    dialect, listen = request.param
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", "table", "--dialect", dialect,
                             "--listen", listen], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, bufsize=1)
    proc.lines = queue.Queue()
    reader = threading.Thread(target=lambda: [proc.lines.put(line) for line in proc.stdout], daemon=True)
    reader.start()
    try:
        first = _read_line(proc)
        assert "listening on" in first, first + proc.stderr.read() if proc.poll() is not None else first
        assert "fault console" in _read_line(proc)
        yield proc, dialect, first.rsplit(" ", 1)[1].strip()
    finally:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(timeout=5)
        reader.join(timeout=5)
        for stream in (proc.stdin, proc.stdout, proc.stderr):
            stream.close()


def _fault(proc: subprocess.Popen, command: str) -> str:
    proc.stdin.write(command + "\n")
    proc.stdin.flush()
    return _read_line(proc).strip()


@pytest.mark.parametrize("simulator", [("scpi", "tcp://127.0.0.1:0"), ("mn", "pty"),
                                       ("modbus", "modbus+tcp://127.0.0.1:0"), ("acutrol", "tcp://127.0.0.1:0"),
                                       ("acutrol", "pty")], indirect=True)
def test_operator_session_against_the_served_simulator(simulator, capsys, monkeypatch):
    proc, dialect, url = simulator
    base = ["table", "--url", url, "--dialect", dialect, "--timeout-s", "0.5"]
    assert main(base + ["status"]) == 0
    # a refused move says why in the same words in every dialect (Modbus itself says only "exception 4")
    assert main(base + ["goto", "10", "0", "0"]) == 3
    assert "refused: outer, middle, inner axes not enabled (controller: " in capsys.readouterr().err
    assert main(base + ["rate", "inner", "5"]) == 3
    assert "refused: inner axis not enabled (controller: " in capsys.readouterr().err
    assert main(base + ["enable"]) == 0
    capsys.readouterr()
    monkeypatch.setattr(sys.stderr, "isatty", lambda: True)     # a terminal: goto shows its progress
    assert main(base + ["goto", "10", "-5", "20", "--rate-dps", "50"]) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert "10.000000" in out and "-5.000000" in out and "enabled, in position" in out
    assert captured.err.startswith("\rmoving: outer") and captured.err.endswith("\r"), captured.err
    assert main(base + ["--max-rate-dps", "10", "goto", "0", "0", "0", "--rate-dps", "20"]) == 2
    assert "nothing sent" in capsys.readouterr().err
    assert main(base + ["rate", "inner", "-30"]) == 0
    assert main(base + ["stop"]) == 0
    assert _fault(proc, "estop") == "ok"
    assert main(base + ["status"]) == 3
    assert "emergency stop active" in capsys.readouterr().out
    assert main(base + ["goto", "0", "0", "0"]) == 3
    assert "TurntableEStop" in capsys.readouterr().err
    assert _fault(proc, "release") == "ok"
    assert main(base + ["reset"]) == 0
    assert main(base + ["abort"]) == 0
    assert "off" in capsys.readouterr().out
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=10) == 0


@pytest.mark.parametrize("simulator", [("scpi", "tcp://127.0.0.1:0")], indirect=True)
def test_fault_console_timeouts_become_exit_6_table_state_unknown(simulator, capsys):
    proc, dialect, url = simulator
    assert _fault(proc, "timeout 10") == "ok"
    t0 = time.monotonic()
    # the read times out, and so do the stop and the abort after it: nothing confirms the table's state
    assert main(["table", "--url", url, "--dialect", dialect, "--timeout-s", "0.2", "--retries", "1",
                 "status"]) == 6
    assert time.monotonic() - t0 < 5
    err = capsys.readouterr().err
    assert "TurntableTimeout" in err and "TABLE STATE UNKNOWN: the controller cannot be reached" in err, err
    assert len(err.strip().splitlines()) == 1
    assert _fault(proc, "bogus") == "unknown command 'bogus'; type help"


def test_unreachable_controller_and_usage_errors(capsys):
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
        # nothing was sent: exit 2, as `bench run` says of a table it cannot reach (README's exit codes)
        assert main(["table", "--url", f"tcp://127.0.0.1:{port}", "--dialect", "scpi", "status"]) == 2
        err = capsys.readouterr().err
        assert "cannot reach the controller" in err and err.strip().endswith("nothing sent") and "dialect" not in err
    assert main(["table", "--url", "tcp://127.0.0.1:1", "status"]) == 2
    assert "say which dialect" in capsys.readouterr().err
    assert main(["table", "--url", "modbus+tcp://127.0.0.1:1", "--dialect", "scpi", "status"]) == 2
    with pytest.raises(SystemExit) as exit_info:
        main(["sim", "table", "--dialect", "nope", "--listen", "pty"])
    assert exit_info.value.code == 2


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_sim_table_stops_on_a_stop_signal_even_when_started_with_sigint_ignored(signum):
    # A shell starts `bench sim table ... &` in a script with SIGINT ignored; Ctrl-C/SIGINT must still stop it,
    # and SIGTERM (kill, systemd) and SIGHUP stop it as they stop the chamber and rig simulators: its
    # listeners closed, exit 0.
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", "table", "--dialect", "scpi", "--listen",
                             "tcp://127.0.0.1:0"], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        assert "listening on" in proc.stdout.readline()
        # the signal while it serves (reading the fault console), not while it still prints its start-up lines
        assert "Ctrl-C stops" in proc.stdout.readline()
        proc.send_signal(signum)
        assert proc.wait(timeout=10) == 0
        assert "stopped" in proc.stderr.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=5)
        for stream in (proc.stdin, proc.stdout, proc.stderr):
            stream.close()


@pytest.mark.parametrize("dialect, where", [
    ("scpi", "tcp://:5025"), ("modbus", "modbus+tcp://:5020"),
    # a port urllib cannot read, a broken IPv6 literal: one line, not a ValueError's traceback
    ("scpi", "tcp://127.0.0.1:99999"), ("mn", "tcp://[::1"), ("modbus", "modbus+tcp://127.0.0.1:abc"),
])
def test_sim_table_refuses_a_listen_address_without_a_host(dialect, where, capsys):
    assert main(["sim", "table", "--dialect", dialect, "--listen", where]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "HOST:PORT" in err, err


@pytest.mark.parametrize("dialect, where", [
    ("scpi", "tcp://0.0.0.0:0"), ("mn", "tcp://[::]:0"), ("modbus", "modbus+tcp://0.0.0.0:0"),
    ("scpi", "tcp://bench-host.example:5025"),        # a name may resolve to anything: remote unless localhost
])
def test_sim_table_refuses_a_non_loopback_address_without_allow_remote(dialect, where, capsys, monkeypatch):
    def no_console():
        raise AssertionError("read stdin before refusing")

    monkeypatch.setattr(sys, "stdin", type("NoStdin", (), {"__iter__": lambda self: no_console()})())
    assert main(["sim", "table", "--dialect", dialect, "--listen", "pty", "--listen", where]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert len(err.splitlines()) == 1 and where in err and "--allow-remote" in err, err
    assert captured.out == ""                     # nothing was served, not even the pty


def test_a_simulator_that_fails_to_close_is_one_line_and_the_rest_still_close(capsys):
    # bench sim table/chamber once let a failing closer raise a traceback and skip the closers after it
    from bench.cli.sim_serving import run_until_stopped

    closed = []

    def serve():
        closers.extend([lambda: closed.append("first"), broken, lambda: closed.append("last")])
        raise KeyboardInterrupt          # Ctrl-C

    def broken():
        raise OSError("the pty is gone")

    closers: list = []
    assert run_until_stopped("bench sim table", serve, closers, usage_errors=(OSError,)) == 0
    assert closed == ["last", "first"]                       # in reverse, past the broken one
    assert capsys.readouterr().err.splitlines() == ["bench sim table: stopped",
                                                    "bench sim table: while closing: OSError: the pty is gone"]


def test_loopback_addresses_need_no_flag():
    from bench.cli.sim_serving import remote_hosts

    assert remote_hosts(["tcp://127.0.0.1:0", "tcp://localhost:1", "tcp://[::1]:2", "modbus+tcp://127.0.0.2:3",
                          "pty"]) == []
    assert remote_hosts(["tcp://127.0.0.1:0", "tcp://10.0.0.5:1"]) == ["tcp://10.0.0.5:1"]


def test_sim_table_with_allow_remote_warns_loudly(capsys, monkeypatch):
    # Without binding beyond loopback in a test: the listener is stood in for and Ctrl-C comes from the console.
    import bench.cli.table as table_cli

    class CtrlC:
        def __iter__(self):
            raise KeyboardInterrupt

    monkeypatch.setattr(table_cli, "start_listener", lambda controller, dialect, where, closers, **options: "tcp://0.0.0.0:5025")
    monkeypatch.setattr(sys, "stdin", CtrlC())
    assert main(["sim", "table", "--dialect", "scpi", "--listen", "tcp://0.0.0.0:5025", "--allow-remote"]) == 0
    captured = capsys.readouterr()
    assert "listening on tcp://0.0.0.0:5025" in captured.out
    warning = [line for line in captured.err.splitlines() if line.startswith("WARNING")]
    assert len(warning) == 1 and "reachable from the NETWORK" in warning[0] and "0.0.0.0:5025" in warning[0]


@pytest.mark.slow
@pytest.mark.parametrize("simulator", [("scpi", "tcp://127.0.0.1:0")], indirect=True)
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_stop_a_goto_like_ctrl_c(simulator, signum, capsys):
    _proc, dialect, url = simulator
    assert main(["table", "--url", url, "--dialect", dialect, "enable"]) == 0
    capsys.readouterr()
    watcher = open_turntable(url, dialect, timeout_s=1.0)
    watcher.connect()
    goto = subprocess.Popen([sys.executable, "-m", "bench.cli", "table", "--url", url, "--dialect", dialect,
                             "goto", "0", "0", "180", "--rate-dps", "10"], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: abs(watcher.read_state().axes[2].rate_dps) > 1.0, 20.0, "the inner frame to turn",
                 proc=goto)
        goto.send_signal(signum)
        _, stderr = goto.communicate(timeout=20)
        assert goto.returncode == 3, stderr
        name = signal.Signals(signum).name
        assert stderr.strip() == f"bench table goto: interrupted ({name}); table commanded to stop"

        def at_rest():
            state = watcher.read_state()
            return state if all(abs(r) < 1e-9 for r in state.rates_dps) else None

        # the table decelerates to rest short of the target (at 10 deg/s it had ~18 s to go)
        state = wait_for(at_rest, 20.0, "the table at rest")
        assert state.axes[2].angle_deg < 170.0
    finally:
        stop_process(goto)
        watcher.close()


# -- bench table on a Modbus controller: register map and watchdog (issue 14, item 4) ----------------

@pytest.fixture
def modbus_controller(tmp_path):
    """A simulated Modbus controller whose map arms a 0.2 s watchdog, served in this process; yields
    (controller, server, url, map file)."""
    from bench.config.load import load_register_map
    from bench.sim.controller import SimController
    from bench.sim.modbus_server import ModbusSimServer

    map_file = tmp_path / "map.toml"
    map_file.write_text("[modbus]\nwatchdog_s = 0.2\n", encoding="utf-8")
    controller = SimController()
    server = ModbusSimServer(controller, load_register_map(map_file))
    host, port = server.start_tcp("127.0.0.1", 0)
    try:
        yield controller, server, f"modbus+tcp://{host}:{port}", map_file
    finally:
        server.close()


@pytest.mark.parametrize("extra", [[], ["--no-watchdog"]], ids=["released on exit", "never armed"])
def test_bench_table_on_modbus_leaves_no_watchdog_to_trip_after_it_ends(modbus_controller, extra, capsys):
    """`bench table enable` armed the watchdog and exited: 2 s later the table faulted, servos off."""
    controller, server, url, map_file = modbus_controller
    assert main(["table", "--url", url, "--register-map", str(map_file), *extra, "enable"]) == 0, \
        capsys.readouterr().err
    time.sleep(1.0)                  # five watchdog periods after the command ended
    state = controller.state()
    assert not server.watchdog_tripped and not state.fault
    assert all(axis.enabled for axis in state.axes)


@pytest.mark.parametrize("args, fragment", [
    (["--url", "tcp://127.0.0.1:9", "--dialect", "scpi", "--no-watchdog", "status"], "for the modbus dialect only"),
    (["--url", "modbus+tcp://127.0.0.1:9", "--register-map", "BAD", "status"],
     ":2: modbus.watchdog_s: must be <= 3600 s"),
])
def test_bench_table_register_map_options_are_checked_before_connecting(tmp_path, args, fragment, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text("[modbus]\nwatchdog_s = 1e9\n", encoding="utf-8")
    args = [str(bad) if a == "BAD" else a for a in args]
    assert main(["table", *args]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and fragment in err, err


@pytest.mark.parametrize("simulator", [("acutrol", "tcp://127.0.0.1:0")], indirect=True)
def test_acutrol_refusals_are_one_line_naming_the_command_and_the_controllers_text(simulator, capsys):
    proc, dialect, url = simulator
    base = ["table", "--url", url, "--dialect", dialect, "--timeout-s", "1.0"]
    # a configured limit beyond the controller's absolute (factory) limits: refused at connect, nothing sent
    assert main(base + ["--max-rate-dps", "500", "enable"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "refused, nothing sent: outer max_rate_dps 500.0 exceeds the controller's " \
                                    "absolute limit 200.0 deg/s" in err, err
    with open_turntable(url, dialect, timeout_s=1.0) as table:
        assert not any(axis.enabled for axis in table.read_state().axes)
        assert main(base + ["enable", "outer"]) == 0
        assert main(base + ["disable", "outer"]) == 0
        assert "outer" in capsys.readouterr().out and not table.read_state().axes[0].enabled
        assert main(base + ["enable"]) == 0
        capsys.readouterr()
        table.set_rate("inner", 20.0)
        assert table.read_state().modes[2].value == "rate"
        assert _fault(proc, "estop") == "ok"
        # an ACL error: one line with the message sent and the controller's text; the table is commanded to stop
        assert main(base + ["reset"]) == 3
        err = capsys.readouterr().err
        assert err.count("\n") == 1, err
        assert "TurntableCommandError: acutrol controller refused ':INT:RES': Interlock fault latched" in err
        assert [mode.value for mode in table.read_state().modes] == ["off"] * 3     # the inner was in rate mode


# -- issue 33, item 13: rate says how to stop, stop waits for rest, unreachable is exit 2, the dialect hint --------

@pytest.mark.parametrize("simulator", [("scpi", "tcp://127.0.0.1:0")], indirect=True)
def test_rate_says_how_to_stop_and_stop_returns_at_rest(simulator, capsys):
    proc, dialect, url = simulator
    base = ["table", "--url", url, "--dialect", dialect, "--timeout-s", "0.5"]
    assert main(base + ["enable"]) == 0
    capsys.readouterr()
    # outer: 100 deg/s at the simulated table's 50 deg/s^2 takes 2 s to brake
    assert main(base + ["rate", "outer", "100"]) == 0
    out = capsys.readouterr().out
    assert f"keeps turning after this command ends: `bench table --url {url} --dialect scpi stop` stops it" in out
    assert main(base + ["stop"]) == 0
    out = capsys.readouterr().out
    assert "moving" not in out and out.splitlines()[1].split()[2] == "0.000000", out
    with open_turntable(url, dialect, timeout_s=0.5) as table:       # an independent look: at rest
        state = table.read_state()
    assert all(rate == 0.0 for rate in state.rates_dps) and not any("moving" in a.status.describe() for a in state.axes)
    proc.send_signal(signal.SIGINT)
    assert proc.wait(timeout=10) == 0


def test_waiting_for_rest_is_bounded_on_the_simulated_clock():
    """`wait_at_rest` on a simulated controller whose clock moves only as the client waits: a stop from 100 deg/s
    brakes in 2 s of its time, so a 0.5 s wait gives up (TurntableTimeout: exit 3 at the CLI) and a 5 s one ends
    at rest."""
    from bench.cli.table import at_rest, wait_at_rest
    from bench.sim.controller import SimController
    from bench.sim.scpi_server import ScpiSimHandler
    from bench.sim.serve import LineServer
    from drivers.clock import ManualClock
    from drivers.errors import TurntableTimeout

    clock = ManualClock()
    with LineServer(ScpiSimHandler(SimController(clock=clock))) as server:
        host, port = server.listen_tcp()
        with open_turntable(f"tcp://{host}:{port}", "scpi", clock=clock, timeout_s=2.0) as table:
            for wait_s, ends_at_rest in ((0.5, False), (5.0, True)):
                table.enable()
                table.set_rate("outer", 100.0)
                clock.advance(3.0)
                table.stop()
                started = clock.now()
                if ends_at_rest:
                    assert at_rest(wait_at_rest(table, wait_s))
                    assert 2.0 - 0.06 <= clock.now() - started <= 2.0 + 0.11
                else:
                    with pytest.raises(TurntableTimeout, match="still moving 0.5 s after the stop"):
                        wait_at_rest(table, wait_s)
                    assert clock.now() - started < 0.7


@pytest.mark.parametrize("simulator", [("mn", "tcp://127.0.0.1:0")], indirect=True)
@pytest.mark.parametrize("dialect", ["scpi", "acutrol"])
def test_a_wrong_dialect_suggests_checking_the_dialect(simulator, dialect, capsys):
    proc, served, url = simulator
    code = main(["table", "--url", url, "--dialect", dialect, "--timeout-s", "0.2", "--retries", "0", "status"])
    err = capsys.readouterr().err
    assert code in (2, 3, 6) and len(err.strip().splitlines()) == 1, err
    assert f"check --dialect {dialect}: a controller speaking another dialect" in err, err
    # the right dialect answers; a fault after the controller answered is no dialect question
    assert main(["table", "--url", url, "--dialect", served, "status"]) == 0
    assert main(["table", "--url", url, "--dialect", served, "--timeout-s", "0.2", "goto", "1", "0", "0"]) == 3
    assert "check --dialect" not in capsys.readouterr().err


def test_the_dialect_hint_is_for_silence_and_unreadable_replies_of_a_table_only():
    from bench.cli.common import dialect_hint
    from drivers.errors import ChamberTimeout, TurntableCommandError, TurntableProtocolError, TurntableTimeout

    option = '[table] dialect = "mn"'
    for error in (TurntableTimeout("mn: no reply"), TurntableProtocolError("bad checksum")):
        assert dialect_hint(error, "mn", option) == (f"check {option}: a controller speaking another dialect "
                                                     "(acutrol, modbus, scpi) gives no reply or replies mn cannot read")
    assert "unit id" in dialect_hint(TurntableTimeout("x"), "modbus", "--dialect modbus")
    assert dialect_hint(TurntableCommandError("refused"), "mn", option) == ""
    assert dialect_hint(ChamberTimeout("no reply"), "mn", option) == ""
