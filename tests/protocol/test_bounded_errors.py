"""Errors that quote a peer's bytes stay short, and a peer streaming garbage cannot grow a driver's buffer
(issue 13 item 11).

`drivers.errors.quote_bytes` is the one helper every such message goes through. The
peers here are raw TCP servers on 127.0.0.1 that answer any request with a stream of
garbage (at most `STREAM_CAP` bytes per connection, so a test is bounded even if a
client never stops reading), the Modbus one without any frame in it.
"""

from __future__ import annotations

import socket
import threading

import pytest

from drivers.errors import QUOTE_LIMIT, TurntableProtocolError, quote_bytes
from drivers.transport import MAX_REPLY_BYTES, LineChannel, TcpTransport
from drivers.turntable import open_turntable

#: a message quoting a peer's data: its own words plus 64 quoted bytes (4 characters each at worst)
SHORT = 400
STREAM_CAP = 8 * 1024 * 1024
WAIT_S = 10.0


def test_quote_bytes_keeps_short_data_whole_and_cuts_long_data_with_its_length():
    assert quote_bytes(b"OK") == "b'OK'"
    assert quote_bytes(b"\xde\xad", hex_dump=True) == "de ad"
    assert quote_bytes("1.5x") == "'1.5x'"
    junk = b"\xde\xad\xbe\xef" * 10_375_000
    quoted = quote_bytes(junk)
    assert quoted == repr(junk[:QUOTE_LIMIT]) + "... (41,500,000 bytes)"
    assert quote_bytes(junk, hex_dump=True) == junk[:QUOTE_LIMIT].hex(" ") + " ... (41,500,000 bytes)"
    assert quote_bytes("x" * 100, 8) == "'xxxxxxxx'... (100 characters)"
    assert quote_bytes(bytearray(b"a" * QUOTE_LIMIT)) == repr(b"a" * QUOTE_LIMIT)   # the limit itself: whole


class GarbagePeer:
    """A TCP server on 127.0.0.1: on every connection, waits for a request, then streams `chunk` repeatedly
    (up to STREAM_CAP bytes) and holds the connection until the client closes it."""

    def __init__(self, chunk: bytes):
        self.chunk = chunk
        self.connections = 0
        self._sock = socket.create_server(("127.0.0.1", 0))
        self._sock.settimeout(0.1)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="test-garbage-peer", daemon=True)
        self._thread.start()

    @property
    def address(self) -> tuple[str, int]:
        return self._sock.getsockname()[:2]

    def _serve(self) -> None:
        while not self._stop.is_set():
            try:
                conn, _ = self._sock.accept()
            except (TimeoutError, socket.timeout):
                continue
            except OSError:
                return
            self.connections += 1
            with conn:
                self._stream(conn)

    def _stream(self, conn: socket.socket) -> None:
        conn.settimeout(WAIT_S)
        try:
            if not conn.recv(4096):
                return
            block = self.chunk * max(1, 65536 // len(self.chunk))
            sent = 0
            while sent < STREAM_CAP and not self._stop.is_set():
                conn.sendall(block)
                sent += len(block)
            while not self._stop.is_set() and conn.recv(65536):   # until the client closes (bounded by timeout)
                pass
        except OSError:             # the client closed or reset: this connection is done
            return

    def close(self) -> None:
        self._stop.set()
        self._sock.close()
        self._thread.join(timeout=WAIT_S)

    def __enter__(self) -> GarbagePeer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _error_from(url: str, dialect: str, ask=lambda table: table.read_state(), retries: int = 1):
    """The protocol error of connecting to `url` and asking (a dialect may ask something as it connects)."""
    table = open_turntable(url, dialect, timeout_s=WAIT_S, retries=retries)
    try:
        with pytest.raises(TurntableProtocolError) as info:
            table.connect()
            ask(table)
    finally:
        table.close()
    return info.value, table


def test_a_modbus_peer_streaming_garbage_ends_in_a_short_error_after_a_bounded_read():
    # no MBAP frame in it (protocol id 0xbeef): pymodbus would keep all of it until the timeout
    with GarbagePeer(bytes.fromhex("de ad be ef 00 ff 13 37 42")) as peer:
        host, port = peer.address
        error, _ = _error_from(f"modbus+tcp://{host}:{port}", "modbus")
    message = str(error)
    assert len(message) < SHORT, f"{len(message):,} characters: {message[:200]}..."
    assert f"no Modbus reply in more than {MAX_REPLY_BYTES:,} bytes" in message and "de ad be ef" in message
    assert error.raw is not None and MAX_REPLY_BYTES < len(error.raw) <= MAX_REPLY_BYTES + 4096   # one read more
    assert peer.connections == 1              # given up on at once, not retried into the same stream


@pytest.mark.parametrize("dialect, chunk, ask, needle", [
    # printable junk without a terminator: the line is cut at max_line (4096) and quoted in the error
    ("scpi", b"x", lambda table: table.read_position(0), "is not a decimal number"),
    # a frame-like line whose "checksum" runs on for 500 characters
    ("mn", b"$ASSTA,1*" + b"Z" * 500 + b"\r\n", lambda table: table.read_state(),
     "checksum must be two upper-case hex digits"),
    # an ACL frame header announcing the longest text a controller sends (32 768 bytes), then junk: one frame read
    ("acutrol", b"\x00\x00\x00\x00\x00\x80\x00\x00", lambda table: table.read_state(), "not printable ASCII"),
], ids=["scpi", "mn", "acutrol"])
def test_a_line_peer_streaming_garbage_ends_in_a_short_error_with_a_bounded_buffer(dialect, chunk, ask, needle):
    with GarbagePeer(chunk) as peer:
        host, port = peer.address
        # one attempt: its line is the stream's first (a retry starts wherever the discarded input ended)
        error, table = _error_from(f"tcp://{host}:{port}", dialect, ask, retries=0)
        assert len(table.channel._buffer) <= table.channel.max_line + 4096
    message = str(error)
    assert needle in message
    assert len(message) < SHORT, f"{len(message):,} characters: {message[:200]}..."


def test_discarding_input_from_a_peer_that_never_pauses_is_bounded():
    with GarbagePeer(b"y") as peer:
        host, port = peer.address
        transport = TcpTransport(f"tcp://{host}:{port}")
        transport.open()
        try:
            channel = LineChannel(transport)
            channel.write_line(b"GO")
            assert channel.read_line(WAIT_S) is not None      # the stream has started: a max_line run of junk
            for _ in range(3):
                channel.discard_input()                         # returns, however fast the peer streams
                assert channel.read_line(WAIT_S) == b"y" * channel.max_line
        finally:
            transport.close()
