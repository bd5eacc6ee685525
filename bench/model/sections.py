"""What the typed sections of a result file share: the format error, an entry's reading by type, and the rule
that keeps a section as it was read.

A section (`Section`) knows its entries in the order the bench writes them. Read from a file (`from_dict`), it
remembers the file's entries in their order (`keys`) and keeps the ones it does not know in `extra`, so that it
writes back exactly what it read (a null where the file had null, nothing where the file had nothing); entries
set later follow the file's (known ones in the section's order, then unknown ones in theirs). Built in code
(`keys` None), it writes its known entries that are not None in its own order, then `extra` (a section whose
file has a null, as a verdict's `worst` when no check ran, is made with `from_dict`). An entry of the wrong type
is refused (`ResultFormatError` naming the section and entry); a missing one is None: older files lack entries
newer ones have.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, Mapping, Self, TypeVar

from bench.errors import InputError


class ResultFormatError(InputError):
    """A result file that is not a turntable-bench result of a version we read."""


T = TypeVar("T")
Reader = Callable[[Any, str], Any]


@dataclass
class Section:
    """Base of a result section (see the module docstring); a subclass lists its readers in `READERS`."""

    #: entry name -> its reader (value, where -> the field's value; ResultFormatError when malformed), in the
    #: order the bench writes the entries
    READERS: ClassVar[Mapping[str, Reader]] = {}

    extra: dict[str, Any] = field(default_factory=dict, kw_only=True)      # entries this software does not know
    keys: tuple[str, ...] | None = field(default=None, kw_only=True, compare=False, repr=False)   # as read

    def _dumped(self, name: str) -> Any:
        """The JSON value of the known entry `name` (a subclass turns its typed values into JSON here)."""
        value = getattr(self, name)
        return value.to_dict() if isinstance(value, Section) else value

    def to_dict(self) -> dict[str, Any]:
        known = {name: self._dumped(name) for name in self.READERS}
        out: dict[str, Any] = {}
        for key in self.keys or ():
            if key in known:
                out[key] = known[key]
            elif key in self.extra:
                out[key] = self.extra[key]
        out |= {k: v for k, v in known.items() if k not in out and v is not None}
        return out | {k: v for k, v in self.extra.items() if k not in out}

    @classmethod
    def _read(cls, data: Any, where: str) -> dict[str, Any]:
        """The keyword arguments of `cls` from a section's JSON `data` (every known entry, None when missing)."""
        if not isinstance(data, Mapping):
            raise ResultFormatError(f"{where} must be an object")
        known: dict[str, Any] = {name: None for name in cls.READERS}
        for name, reader in cls.READERS.items():
            if name in data and data[name] is not None:
                known[name] = reader(data[name], f"{where}.{name}")
        extra = {str(k): v for k, v in data.items() if k not in cls.READERS}
        return known | {"extra": extra, "keys": tuple(str(k) for k in data)}

    @classmethod
    def from_dict(cls, data: Any, where: str = "section") -> Self:
        """The section of a file (ResultFormatError naming `where` and the entry when one is malformed)."""
        return cls(**cls._read(data, where))


# -- readers of one entry: the value as the field holds it, or ResultFormatError naming where ---------------------

def text(value: Any, where: str) -> str:
    if not isinstance(value, str):
        raise ResultFormatError(f"{where} must be a string, got {value!r:.60}")
    return value


def flag(value: Any, where: str) -> bool:
    if not isinstance(value, bool):
        raise ResultFormatError(f"{where} must be true or false, got {value!r:.60}")
    return value


def count(value: Any, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ResultFormatError(f"{where} must be a whole number, got {value!r:.60}")
    return value


def number(value: Any, where: str) -> float:
    """A finite JSON number as it was written (an int stays an int: the file is written back the same)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ResultFormatError(f"{where} must be a finite number, got {value!r:.60}")
    return value


def obj(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, Mapping):
        raise ResultFormatError(f"{where} must be an object")
    return dict(value)


def list_of(item: Callable[[Any, str], T]) -> Callable[[Any, str], list[T]]:
    """The reader of a list whose items `item` reads."""
    def read(value: Any, where: str) -> list[T]:
        if not isinstance(value, list):
            raise ResultFormatError(f"{where} must be a list")
        return [item(v, f"{where}[{i}]") for i, v in enumerate(value)]
    return read


def or_null(item: Callable[[Any, str], T]) -> Callable[[Any, str], T | None]:
    """The reader of an item that may be null."""
    return lambda value, where: None if value is None else item(value, where)


__all__ = ["ResultFormatError", "Section", "count", "flag", "list_of", "number", "obj", "or_null", "text"]
