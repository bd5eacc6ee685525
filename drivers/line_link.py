"""Request/reply machinery shared by every line dialect (turntable SCPI-like and $MN, chamber ASCII).

`LineRequests._transact` sends one request line and parses one reply line with the
dialect's pure codec. What goes wrong is handled here once for every dialect, raising
the device's own errors (`link_errors`, a `drivers.errors.LinkErrors`):
- no reply within `timeout_s`: retry (input discarded first), then `timeout`;
- a controller that was only slow answers the timed-out attempts as well: the reply that
  comes first answers the request (it is the same request), and the replies still owed
  are read and dropped before the call returns (each waited for at most `timeout_s`).
  Otherwise every later call would read the reply to the call before it: a state one
  poll old, for the rest of the session;
- a reply the codec rejects (garbage, bad checksum, wrong echo): retry, then that error;
- the link drops: reopen the transport once per attempt, then `connection`;
- the controller refuses the command (`command`): raised at once, a retry would be
  refused the same way.
Every retry and reconnect is counted in `stats`, so a run can log link quality.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, TypeVar

from drivers.errors import LinkErrors
from drivers.transport import ByteTransport, LineChannel, open_transport

T = TypeVar("T")


@dataclass
class LinkStats:
    requests: int = 0
    timeouts: int = 0
    protocol_errors: int = 0
    reconnects: int = 0
    late_replies: int = 0     # replies to timed-out attempts, read and dropped


class LineRequests:
    """One request line -> one reply line over a byte transport (a mixin of the line clients).

    `_setup_link` sets the transport (a URL is opened with `open_transport`), timeout and
    retries; the class gives `dialect`, `link_errors` and `terminator`.
    """

    dialect: str = ""
    link_errors: LinkErrors
    terminator = b"\r\n"
    transport: ByteTransport
    channel: LineChannel
    timeout_s: float
    retries: int
    stats: LinkStats

    def _setup_link(self, transport: ByteTransport | str, timeout_s: float, retries: int) -> None:
        if timeout_s <= 0 or retries < 0:
            raise self.link_errors.config(f"timeout_s must be positive and retries >= 0, got {timeout_s}, {retries}")
        if isinstance(transport, str):
            try:
                transport = open_transport(transport)
            except ValueError as exc:       # the transports' own config error, under this device's name
                if isinstance(exc, self.link_errors.config):
                    raise
                raise self.link_errors.config(str(exc)) from exc
        self.transport = transport
        self.channel = LineChannel(self.transport)
        self.timeout_s, self.retries = timeout_s, retries
        self.stats = LinkStats()

    @property
    def url(self) -> str:
        return self.transport.url

    def _open_link(self) -> None:
        try:
            self.transport.open()
        except ConnectionError as exc:
            raise self.link_errors.connection(f"{self.dialect}: {exc}") from exc
        self.channel.discard_input()

    def _open(self) -> None:
        self._open_link()

    def _close(self) -> None:
        self.transport.close()

    def _transact(self, request: bytes, parse: Callable[[bytes], T]) -> T:
        """Send `request` (without terminator) and return `parse(reply line)`, retrying as above."""
        errors = self.link_errors
        last: Exception | None = None
        unanswered = 0       # attempts of this request that timed out: a slow controller still answers them
        for attempt in range(self.retries + 1):
            self.stats.requests += 1
            try:
                if not self.transport.is_open:
                    self.stats.reconnects += 1
                    self._open()
                elif attempt:
                    self.channel.discard_input()
                self.channel.write_line(request, self.terminator)
                line = self.channel.read_line(self.timeout_s)
            except ConnectionError as exc:
                # the device's own connection error is a ConnectionError too: a failed reopen
                if isinstance(exc, errors.connection):
                    last = exc
                    continue
                self.transport.close()
                last = errors.connection(f"{self.dialect} link {self.url} lost: {exc}")
                last.__cause__ = exc
                continue
            if line is None:
                self.stats.timeouts += 1
                unanswered += 1
                last = errors.timeout(f"{self.dialect}: no reply to {request!r} from {self.url} "
                                      f"within {self.timeout_s} s ({attempt + 1} attempts)")
                continue
            if unanswered:
                # `line` answers the first attempt still owed a reply (replies come in order);
                # the replies to the later attempts would answer the next calls
                self._drop_late_replies(unanswered)
            try:
                return parse(line)
            except errors.protocol as exc:
                self.stats.protocol_errors += 1
                last = exc
        assert last is not None
        raise last

    def _drop_late_replies(self, owed: int) -> None:
        """Read and drop up to `owed` replies, each waited for at most `timeout_s` (a request lost on
        the way is never answered: its wait ends the drain)."""
        for _ in range(owed):
            try:
                line = self.channel.read_line(self.timeout_s)
            except ConnectionError:
                self.transport.close()     # the next call reopens the link
                return
            if line is None:
                return
            self.stats.late_replies += 1
