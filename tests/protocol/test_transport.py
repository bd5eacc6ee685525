"""Byte transports by URL, the line channel, and the simulators' line server (TCP and pty)."""

from __future__ import annotations

import socket

import pytest

from bench.sim.serve import LineServer
from drivers.transport import LineChannel, SerialTransport, TcpTransport, open_transport, serial_settings


def _echo_upper(line: bytes) -> bytes | None:
    if line == b"SILENT":
        return None
    return line.upper() + b"\r\n"


@pytest.fixture
def server():
    srv = LineServer(_echo_upper)
    yield srv
    srv.close()


def test_url_dispatch_and_bad_urls():
    assert isinstance(open_transport("tcp://127.0.0.1:5000"), TcpTransport)
    assert isinstance(open_transport("loop://"), SerialTransport)
    assert isinstance(open_transport("/dev/ttyUSB0?baud=115200"), SerialTransport)
    with pytest.raises(ValueError, match="empty"):
        open_transport("")
    with pytest.raises(ValueError, match="Modbus"):
        open_transport("modbus+tcp://127.0.0.1:502")
    with pytest.raises(ValueError, match="tcp://host:port"):
        TcpTransport("tcp://127.0.0.1")


def test_serial_settings_from_query():
    assert serial_settings("baud=115200&parity=e&stopbits=1") == {"baudrate": 115200, "parity": "E", "stopbits": 1.0}
    with pytest.raises(ValueError, match="unknown serial option 'speed'"):
        serial_settings("speed=9600")
    with pytest.raises(ValueError, match="not a number"):
        serial_settings("baud=fast")
    with pytest.raises(ValueError, match="parity"):
        serial_settings("parity=X")


def test_line_channel_over_loop_handles_cr_lf_and_timeouts():
    transport = open_transport("loop://")
    transport.open()
    try:
        channel = LineChannel(transport)
        transport.write(b"one\r\ntwo\rthree\n\r\nfour")
        assert [channel.read_line(0.2) for _ in range(3)] == [b"one", b"two", b"three"]
        assert channel.read_line(0.05) is None          # "four" has no terminator yet
        transport.write(b"\r\n")
        assert channel.read_line(0.2) == b"four"
    finally:
        transport.close()


def test_line_channel_bounds_garbage_without_terminator():
    transport = open_transport("loop://")
    transport.open()
    try:
        channel = LineChannel(transport, max_line=16)
        transport.write(b"x" * 40)
        assert channel.read_line(0.2) == b"x" * 16
    finally:
        transport.close()


def test_tcp_round_trip_and_connection_loss(server):
    host, port = server.listen_tcp()
    transport = TcpTransport(f"tcp://{host}:{port}")
    transport.open()
    channel = LineChannel(transport)
    channel.write_line(b"hello")
    assert channel.read_line(1.0) == b"HELLO"
    channel.write_line(b"SILENT")
    assert channel.read_line(0.05) is None
    server.close()                                       # the peer goes away
    with pytest.raises(ConnectionError):
        for _ in range(3):                               # a write may still be buffered; a read sees the close
            channel.write_line(b"again")
            channel.read_line(0.5)
    assert not transport.is_open


def test_tcp_refused_is_a_connection_error():
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]                    # bound, never listening: connect is refused
        with pytest.raises(ConnectionError, match="cannot connect"):
            TcpTransport(f"tcp://127.0.0.1:{port}").open()


def test_pty_round_trip(server):
    path = server.open_pty()
    transport = open_transport(path)
    transport.open()
    try:
        channel = LineChannel(transport)
        for word in (b"alpha", b"beta"):
            channel.write_line(word)
            assert channel.read_line(1.0) == word.upper()
    finally:
        transport.close()
    # A second client on the same pty after the first closed.
    transport.open()
    try:
        channel = LineChannel(transport)
        channel.write_line(b"gamma", b"\r")
        assert channel.read_line(1.0) == b"GAMMA"
    finally:
        transport.close()


def test_missing_device_is_a_connection_error():
    with pytest.raises(ConnectionError, match="cannot open"):
        open_transport("/dev/does-not-exist-turntable").open()
