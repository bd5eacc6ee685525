"""A device family's dialects, loaded lazily by name (shared by `drivers.turntable` and `drivers.chamber`).

`Dialects(device, classes, config_error)` maps a dialect name to its client class ("module:class", imported
only when asked for, so importing an interface does not import pymodbus) and opens a driver for a URL.
"""

from __future__ import annotations

import importlib
from typing import Callable, Generic, Mapping, TypeVar

from drivers.transport import MODBUS_SCHEMES

DeviceT = TypeVar("DeviceT")


class Dialects(Generic[DeviceT]):
    """The dialects of one device family; errors are `config_error` (a ValueError) naming the known ones."""

    def __init__(self, device: str, classes: Mapping[str, str], config_error: type[ValueError]):
        self.device, self.classes, self.config_error = device, classes, config_error

    def dialect_class(self, dialect: str) -> type[DeviceT]:
        """The client class of a dialect; the family's config error naming the known ones otherwise."""
        try:
            module, _, name = self.classes[dialect.lower()].partition(":")
        except (KeyError, AttributeError):
            raise self.config_error(f"unknown {self.device} dialect {dialect!r} "
                                    f"(known: {', '.join(self.classes)})") from None
        return getattr(importlib.import_module(module), name)

    def check_url_dialect(self, url: str, dialect: str, *, dialect_label: str = "the dialect") -> None:
        """The family's config error when `url` cannot carry `dialect`: Modbus URLs are for the modbus dialect
        only. `dialect_label` names the dialect's source in the message (e.g. "table.dialect")."""
        is_modbus_url = url.startswith(MODBUS_SCHEMES)
        if dialect.lower() == "modbus" and not is_modbus_url:
            raise self.config_error(f"the modbus dialect needs a modbus+tcp:// or modbus+rtu:// url, got {url!r}")
        if dialect.lower() != "modbus" and is_modbus_url:
            raise self.config_error(f"{url!r} is a Modbus url but {dialect_label} is {dialect!r}")

    def open(self, url: str, dialect: str | None = None, **options) -> DeviceT:
        """An unconnected driver for `url` in `dialect` (`modbus+...` URLs imply 'modbus').

        `options` go to the dialect's constructor (limits, clock, timeout_s, retries, register_map for modbus).
        """
        if dialect is None:
            if not url.startswith(MODBUS_SCHEMES):
                raise self.config_error(f"say which dialect {url!r} speaks (known: {', '.join(self.classes)})")
            dialect = "modbus"
        self.check_url_dialect(url, dialect)
        # Each dialect's constructor takes the URL (or transport) first: not the interface's __init__ signature.
        make: Callable[..., DeviceT] = self.dialect_class(dialect)
        return make(url, **options)


__all__ = ["Dialects"]
