"""The turntable's line dialects (SCPI-like, $MN, ACUTROL3000 ACL): a `Turntable` over `drivers.line_link.LineRequests`.

The request/reply machinery (retries, late replies, reconnects, `stats`) is shared with
the chamber's ASCII dialect and documented in `drivers.line_link`.
"""

from __future__ import annotations

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import TURNTABLE_LINK_ERRORS
from drivers.line_link import LineRequests, LinkStats
from drivers.transport import ByteTransport
from drivers.turntable.base import Turntable, TurntableLimits

__all__ = ["LineTurntable", "LinkStats"]


class LineTurntable(LineRequests, Turntable):
    """A turntable whose controller speaks one request line -> one reply line."""

    link_errors = TURNTABLE_LINK_ERRORS

    def __init__(self, transport: ByteTransport | str, limits: TurntableLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2):
        Turntable.__init__(self, limits, clock)
        self._setup_link(transport, timeout_s, retries)
