"""The simulators' servers stay bounded (issue 13 item 10): connections forgotten when they end,
a cap on concurrent ones (the excess refused, the rest served), an accept loop that outlives
per-connection failures, (`bench sim table` binding beyond loopback only when told: tests/protocol/test_table_cli.py).

Everything runs on 127.0.0.1; waits are bounded polls on the server's own counters.
"""

from __future__ import annotations

import socket
import threading

import pytest

from bench.sim.serve import MAX_CONNECTIONS, LineServer
from tests.helpers.run import wait_for

WAIT_S = 10.0


def echo(line: bytes) -> bytes:
    return b"echo " + line + b"\n"


def _connect(address) -> socket.socket:
    sock = socket.create_connection(address, timeout=WAIT_S)
    sock.settimeout(WAIT_S)
    return sock


def _ask(sock: socket.socket, line: bytes) -> bytes:
    sock.sendall(line + b"\n")
    reply = b""
    for _ in range(100):                   # a reply is one short line
        chunk = sock.recv(4096)
        if not chunk:
            break
        reply += chunk
        if reply.endswith(b"\n"):
            break
    return reply


def _closed_by_peer(sock: socket.socket) -> bool:
    """True if the peer closed `sock` (EOF or reset); blocks up to the socket's timeout."""
    try:
        return sock.recv(1) == b""
    except ConnectionResetError:
        return True


def test_connections_are_forgotten_when_they_end():
    with LineServer(echo) as server:
        address = server.listen_tcp("127.0.0.1", 0)
        for k in range(200):
            with _connect(address) as sock:
                assert _ask(sock, b"%d" % k) == b"echo %d\n" % k
        wait_for(lambda: server.connections == 0, WAIT_S, "every connection to end")
        # the listener's thread and socket, nothing per connection
        assert len(server._threads) == 1 and len(server._closers) == 1
        assert len(server._connections) == 0


def test_a_new_client_beyond_the_cap_closes_the_longest_idle_connection_and_is_served():
    """Issue 34 item 10: idle connections cannot lock a client out; the one silent longest makes room."""
    with LineServer(echo) as server:
        address = server.listen_tcp("127.0.0.1", 0)
        served = []
        try:
            for k in range(MAX_CONNECTIONS):
                served.append(_connect(address))
                wait_for(lambda n=k + 1: server.connections == n, WAIT_S, f"{k + 1} connections served")
            for sock in served[1:]:            # every one but the first has spoken since it connected
                assert _ask(sock, b"here") == b"echo here\n"
            with _connect(address) as fresh:
                assert _ask(fresh, b"served") == b"echo served\n"
                assert _closed_by_peer(served[0])        # the longest idle made room
                assert server.evicted == 1
                assert _ask(served[-1], b"still here") == b"echo still here\n"
                assert server.connections == MAX_CONNECTIONS
        finally:
            for sock in served:
                sock.close()


def test_an_idle_connection_is_closed_after_the_idle_timeout():
    with LineServer(echo, idle_timeout_s=0.3) as server:
        address = server.listen_tcp("127.0.0.1", 0)
        with _connect(address) as talking, _connect(address) as silent:
            assert _ask(talking, b"hi") == b"echo hi\n"
            assert _closed_by_peer(silent)
            wait_for(lambda: server.timed_out >= 1, WAIT_S, "the idle timeout")
        wait_for(lambda: server.connections == 0, WAIT_S, "every connection to end")
    with pytest.raises(ValueError, match="idle_timeout_s"):
        LineServer(echo, idle_timeout_s=0.0)


def test_socketcand_closes_idle_clients_and_makes_room_for_a_new_one():
    from bench.sim.socketcand_server import MAX_CONNECTIONS as SOCKETCAND_MAX
    from bench.sim.socketcand_server import SocketcandServer

    with SocketcandServer(idle_timeout_s=0.3) as server:
        with _connect((server.host, server.port)) as silent:
            assert silent.recv(64).startswith(b"< hi >")
            assert _closed_by_peer(silent)              # read its greeting, then said and took nothing
        wait_for(lambda: server.timed_out == 1 and server.connections == 0, WAIT_S, "the idle client to go")
    with SocketcandServer() as server:
        held = []
        try:
            for k in range(SOCKETCAND_MAX):
                held.append(_connect((server.host, server.port)))
                wait_for(lambda n=k + 1: server.connections == n, WAIT_S, f"{k + 1} socketcand clients")
            with _connect((server.host, server.port)) as fresh:
                assert fresh.recv(64).startswith(b"< hi >")     # served
                wait_for(lambda: server.evicted == 1, WAIT_S, "the longest idle client to make room")
        finally:
            for sock in held:
                sock.close()


def test_the_accept_loop_survives_a_connection_thread_that_cannot_start():
    failures = []

    class FailsOnce(threading.Thread):
        def start(self) -> None:
            if not failures:
                failures.append(self.name)
                raise RuntimeError("can't start new thread")
            super().start()

    with LineServer(echo) as server:
        server._thread_factory = FailsOnce
        address = server.listen_tcp("127.0.0.1", 0)
        with _connect(address) as first:
            assert _closed_by_peer(first)  # its thread could not start: closed, not left hanging
        assert failures
        with _connect(address) as second:
            assert _ask(second, b"ok") == b"echo ok\n"
            assert server.connections == 1      # the failed one was not kept


# -- the Modbus simulator: the same bounds ----------------------------------------------------

@pytest.fixture
def modbus_server():
    from bench.sim.controller import SimController
    from bench.sim.modbus_server import ModbusSimServer

    with ModbusSimServer(SimController()) as server:
        yield server, server.start_tcp("127.0.0.1", 0)


def _modbus_read_state(host: str, port: int):
    from drivers.turntable import open_turntable

    with open_turntable(f"modbus+tcp://{host}:{port}", "modbus", timeout_s=2.0) as table:
        return table.read_state()


def test_modbus_connections_are_forgotten_when_they_end(modbus_server):
    server, address = modbus_server
    for _ in range(200):       # (a burst of them may meet the cap: closed ones count until the server sees EOF)
        _connect(address).close()
    wait_for(lambda: server.connections == 0, WAIT_S, "every Modbus connection to end")
    assert _modbus_read_state(*address).axes


def test_modbus_a_new_client_beyond_the_cap_closes_the_longest_idle_and_is_served(modbus_server):
    server, address = modbus_server
    idle = []
    try:
        for k in range(MAX_CONNECTIONS):
            idle.append(_connect(address))
            wait_for(lambda n=k + 1: server.connections == n, WAIT_S, f"{k + 1} Modbus connections")
        assert _modbus_read_state(*address).axes      # a new client is served: the longest idle made room
        assert server.evicted == 1 and server.refused == 0
        assert _closed_by_peer(idle[0])
    finally:
        for sock in idle:
            sock.close()


def test_modbus_idle_connections_are_closed_after_the_idle_timeout():
    from bench.sim.controller import SimController
    from bench.sim.modbus_server import ModbusSimServer

    with ModbusSimServer(SimController(), idle_timeout_s=0.3) as server:
        address = server.start_tcp("127.0.0.1", 0)
        with _connect(address) as silent:
            wait_for(lambda: server.connections == 1, WAIT_S, "the connection")
            assert _closed_by_peer(silent)
        wait_for(lambda: server.connections == 0, WAIT_S, "the idle connection to end")
        assert _modbus_read_state(*address).axes


def test_the_command_lines_idle_timeout_option_reaches_the_servers():
    from bench.cli.main import build_parser
    from bench.cli.sim_serving import IDLE_TIMEOUT_S as CLI_DEFAULT
    from bench.sim.serve import IDLE_TIMEOUT_S

    assert CLI_DEFAULT == IDLE_TIMEOUT_S
    parser = build_parser()
    for argv in (["sim", "table", "--dialect", "scpi", "--listen", "pty"], ["sim", "rig"],
                 ["sim", "chamber", "--dialect", "ascii", "--listen", "pty"]):
        assert parser.parse_args(argv).idle_timeout_s == IDLE_TIMEOUT_S
        assert parser.parse_args([*argv, "--idle-timeout-s", "2.5"]).idle_timeout_s == 2.5
        with pytest.raises(SystemExit):
            parser.parse_args([*argv, "--idle-timeout-s", "0"])
