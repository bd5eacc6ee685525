"""Expected-exchange transport for client tests (after pymeasure's `expected_protocol`).

`Exchange([(sent, reply), ...])` is a `ByteTransport`: each write must be exactly the
next `sent` bytes; its `reply` (bytes, or None for silence = a timeout) is then what
reads return. `assert_done()` fails if any pair was left over; use it as a context
manager to check that on exit.
"""

from __future__ import annotations


class Exchange:
    url = "exchange://"

    def __init__(self, pairs: list[tuple[bytes, bytes | None]]):
        self.pairs = list(pairs)
        self.sent: list[bytes] = []
        self._pending = bytearray()
        self._open = False
        self.opened = 0

    @property
    def is_open(self) -> bool:
        return self._open

    def open(self) -> None:
        self._open = True
        self.opened += 1

    def close(self) -> None:
        self._open = False

    def write(self, data: bytes) -> None:
        if not self._open:
            raise ConnectionError("exchange transport is closed")
        self.sent.append(bytes(data))
        if not self.pairs:
            raise AssertionError(f"unexpected write {data!r}: no exchange left")
        expected, reply = self.pairs.pop(0)
        if data != expected:
            raise AssertionError(f"sent {data!r}, expected {expected!r}")
        if reply:
            self._pending += reply

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        if not self._open:
            raise ConnectionError("exchange transport is closed")
        out = bytes(self._pending[:max_bytes])
        del self._pending[:max_bytes]
        return out

    def discard_input(self) -> None:
        self._pending.clear()

    def assert_done(self) -> None:
        assert not self.pairs, f"exchanges left over: {self.pairs!r}"
        assert not self._pending, f"reply bytes never read: {bytes(self._pending)!r}"

    def __enter__(self) -> "Exchange":
        return self

    def __exit__(self, exc_type, *rest) -> None:
        if exc_type is None:
            self.assert_done()
