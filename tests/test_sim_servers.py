"""The simulators' servers stay bounded (issue 13 item 10): connections forgotten when they end,
a cap on concurrent ones (the excess refused, the rest served), an accept loop that outlives
per-connection failures, (`bench sim table` binding beyond loopback only when told: tests/test_table_cli.py).

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


def test_connections_beyond_the_cap_are_refused_and_the_rest_served():
    with LineServer(echo) as server:
        address = server.listen_tcp("127.0.0.1", 0)
        served = []
        try:
            for k in range(MAX_CONNECTIONS):
                served.append(_connect(address))
                wait_for(lambda n=k + 1: server.connections == n, WAIT_S, f"{k + 1} connections served")
            for k in range(5):             # the excess: accepted and closed at once
                with _connect(address) as extra:
                    assert _closed_by_peer(extra)
                assert server.refused == k + 1
            assert server.connections == MAX_CONNECTIONS
            assert _ask(served[0], b"still here") == b"echo still here\n"
            for sock in served[:3]:
                sock.close()
            wait_for(lambda: server.connections == MAX_CONNECTIONS - 3, WAIT_S, "three connections to end")
            with _connect(address) as fresh:
                assert _ask(fresh, b"served") == b"echo served\n"
        finally:
            for sock in served:
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


def test_modbus_connections_beyond_the_cap_are_refused_and_the_rest_served(modbus_server):
    server, address = modbus_server
    idle = []
    try:
        for k in range(MAX_CONNECTIONS):
            idle.append(_connect(address))
            wait_for(lambda n=k + 1: server.connections == n, WAIT_S, f"{k + 1} Modbus connections")
        for k in range(5):
            with _connect(address) as extra:
                assert _closed_by_peer(extra)
            assert server.refused == k + 1
        assert server.connections == MAX_CONNECTIONS
        for sock in idle[:3]:
            sock.close()
        wait_for(lambda: server.connections == MAX_CONNECTIONS - 3, WAIT_S, "three Modbus connections to end")
        assert _modbus_read_state(*address).axes      # a new client is served
    finally:
        for sock in idle:
            sock.close()
