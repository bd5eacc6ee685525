"""A `ByteTransport` over a VISA resource (`visa://GPIB0::1::INSTR`, `visa://TCPIP0::host::9878::SOCKET`).

pyvisa is an optional extra (`pip install turntable-bench[visa]`): it is imported when a `visa://` URL
is opened, never before. The backend is pyvisa's default unless the URL names one
(`visa://TCPIP0::host::9878::SOCKET?backend=@py` for pyvisa-py).

`read(max_bytes, timeout_s)` returns at most `max_bytes`, at the end of a message (EOI on GPIB) or at
a LF when `line_mode` is on, or b"" when nothing came in time: a caller that knows how many bytes a
frame has asks for exactly that many.
"""

from __future__ import annotations

from typing import Any
from urllib.parse import parse_qs

from drivers.errors import TurntableConfigError

SCHEME = "visa://"


def is_visa_url(url: str) -> bool:
    return url.startswith(SCHEME)


def parse_visa_url(url: str) -> tuple[str, str | None]:
    """visa://RESOURCE[?backend=B] -> (resource, backend or None); TurntableConfigError when malformed."""
    if not is_visa_url(url):
        raise TurntableConfigError(f"expected visa://RESOURCE, got {url!r}")
    resource, _, query = url[len(SCHEME):].partition("?")
    options = parse_qs(query, keep_blank_values=True)
    unknown = set(options) - {"backend"}
    if not resource or "::" not in resource or unknown:
        raise TurntableConfigError(f"expected visa://RESOURCE[?backend=@py] (e.g. visa://GPIB0::1::INSTR), got {url!r}"
                                   + (f" (unknown option {sorted(unknown)[0]!r})" if unknown else ""))
    backend = options.get("backend", [None])[-1]
    return resource, backend or None


def is_message_based_gpib(url: str) -> bool:
    """A GPIB instrument (answers queries only, ends a message with EOI) rather than a raw socket or serial port."""
    resource, _ = parse_visa_url(url)
    return resource.upper().startswith("GPIB")


class VisaTransport:
    """A VISA resource as a byte stream (one session, opened on `open()`)."""

    def __init__(self, url: str, line_mode: bool = False):
        self.url = url
        self.resource, self.backend = parse_visa_url(url)
        self.line_mode = line_mode
        self._manager: Any = None
        self._inst: Any = None

    @property
    def is_open(self) -> bool:
        return self._inst is not None

    def open(self) -> None:
        self.close()
        try:
            import pyvisa  # optional extra: only a visa:// URL needs it
        except ImportError as exc:
            raise TurntableConfigError("visa:// URLs need pyvisa (pip install 'turntable-bench[visa]')") from exc
        try:
            self._manager = pyvisa.ResourceManager(self.backend) if self.backend else pyvisa.ResourceManager()
            inst = self._manager.open_resource(self.resource)
            inst.read_termination = "\n" if self.line_mode else None
            inst.write_termination = ""
            self._inst = inst
        except (pyvisa.Error, OSError, ValueError) as exc:
            self.close()
            raise ConnectionError(f"cannot open {self.url}: {exc}") from exc

    def close(self) -> None:
        inst, manager, self._inst, self._manager = self._inst, self._manager, None, None
        for thing in (inst, manager):
            if thing is not None:
                try:
                    thing.close()
                except Exception:  # noqa: BLE001 - closing a session that already failed
                    pass

    def _require(self) -> Any:
        if self._inst is None:
            raise ConnectionError(f"{self.url} is not open")
        return self._inst

    def write(self, data: bytes) -> None:
        import pyvisa  # optional extra: imported by open() already

        inst = self._require()
        try:
            inst.write_raw(data)
        except (pyvisa.Error, OSError) as exc:
            self.close()
            raise ConnectionError(f"write to {self.url} failed: {exc}") from exc

    def read(self, max_bytes: int, timeout_s: float) -> bytes:
        # optional extra: imported by open() already
        import pyvisa
        from pyvisa import constants

        inst = self._require()
        try:
            inst.timeout = max(1, round(timeout_s * 1000))
            with inst.ignore_warning(constants.StatusCode.success_max_count_read):   # a whole frame asked for
                data, _status = inst.visalib.read(inst.session, max_bytes)
        except pyvisa.VisaIOError as exc:
            if exc.error_code == constants.StatusCode.error_timeout:
                return b""
            self.close()
            raise ConnectionError(f"read from {self.url} failed: {exc}") from exc
        except (pyvisa.Error, OSError) as exc:
            self.close()
            raise ConnectionError(f"read from {self.url} failed: {exc}") from exc
        return bytes(data)

    def discard_input(self) -> None:
        """Drop what has arrived (bounded: at most 64 reads that each wait 1 ms)."""
        inst = self._require()
        try:
            inst.flush(16)    # VI_READ_BUF_DISCARD where the backend keeps a buffer
        except Exception:  # noqa: BLE001 - not every backend and resource supports a flush
            pass
        for _ in range(64):
            if not self.read(4096, 0.001):
                return


__all__ = ["VisaTransport", "is_message_based_gpib", "is_visa_url", "parse_visa_url"]
