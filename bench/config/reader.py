"""Typed, located access to a parsed TOML document for `bench.config.load`.

Every problem becomes one `ConfigError` naming the file, the line (from
`schedules.tomllines`) and the dotted key, so the CLI can print one line and exit 2.
Files are read within the limits of `schedules.tomlinput` (a regular file of at most
1 MiB, arrays and inline tables nested at most 32 deep); every number is checked
against its documented range, and the message says the range.
"""

from __future__ import annotations

import datetime
import difflib
import enum
import math
import tomllib
from collections.abc import Iterable
from pathlib import Path
from typing import Any, overload

from bench.errors import InputError
from schedules.tomlinput import InputLimitError, loads, read_text_file, syntax_error_location
from schedules.tomllines import LineMap

_MAX_MESSAGE = 1000  # characters of a message; a 100 kB value quoted back is no help


class _Required(enum.Enum):
    """The type of `_REQUIRED`: "no default, the key must be there" (an enum so it can be typed)."""

    REQUIRED = "required"


_REQUIRED = _Required.REQUIRED


class ConfigError(InputError):
    """A configuration problem, rendered as one line ``path:line: key: message``."""

    def __init__(self, path: str, line: int | None, key: str | None, message: str):
        self.path = str(path)
        self.line = line
        self.key = key
        message = " ".join(str(message).split())  # one line, always
        if len(message) > _MAX_MESSAGE:
            message = f"{message[:_MAX_MESSAGE]}... ({len(message)} characters)"
        self.message = message
        super().__init__(str(self))

    def __reduce__(self):  # picklable despite the custom __init__
        return type(self), (self.path, self.line, self.key, self.message)

    def __str__(self) -> str:
        head = self.path if self.line is None else f"{self.path}:{self.line}"
        return ": ".join([head] + ([self.key] if self.key else []) + [self.message])


def parse_toml(text: str, source: str) -> dict:
    """`tomllib.loads` within the input limits, a syntax error turned into a `ConfigError` with
    tomllib's line."""
    try:
        return loads(text)
    except InputLimitError as exc:  # nested too deep, an integer of thousands of digits
        raise ConfigError(source, exc.line, None, exc.message) from None
    except tomllib.TOMLDecodeError as exc:
        line, message = syntax_error_location(text, exc)
        raise ConfigError(source, line, None, message) from exc


def read_text(path: Path, what: str) -> str:
    """The text of a UTF-8 regular file of at most 1 MiB, or a `ConfigError` saying why it
    cannot be read (a device such as /dev/zero is never read)."""
    try:
        return read_text_file(path)
    except UnicodeDecodeError as exc:
        line = exc.object[:exc.start].count(b"\n") + 1
        raise ConfigError(str(path), line, None, f"cannot read {what}: not UTF-8 text ({exc.reason} at byte "
                                                 f"{exc.start})") from exc
    except InputLimitError as exc:
        raise ConfigError(str(path), None, None, f"cannot read {what}: {exc.message}") from exc
    except OSError as exc:
        raise ConfigError(str(path), None, None, f"cannot read {what}: {exc.strerror or exc}") from exc
    except ValueError as exc:  # a NUL character in the name
        raise ConfigError(show(str(path)), None, None, f"cannot read {what}: {exc}") from exc


def dotted(path: Iterable) -> str:
    """('sim', 'black_box_arcsec', 1) -> 'sim.black_box_arcsec[1]'."""
    out = ""
    for part in path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out


def show(value: object, limit: int = 60) -> str:
    """`repr(value)` for a message, shortened when long (a 400-digit number, a 100 kB string)."""
    if is_number(value) and isinstance(value, int) and abs(value) >= 10 ** 20:
        digits, sign = str(abs(value)), "-" if value < 0 else ""
        return f"{sign}{digits[0]}.{digits[1:4]}e+{len(digits) - 1} (a {len(digits)}-digit integer)"
    text = repr(value)
    return text if len(text) <= limit else f"{text[:limit]}... ({len(text)} characters)"


def number_text(value: float) -> str:
    """A number for a message: `:g` for floats and small integers, `show` for huge integers."""
    return show(value) if isinstance(value, int) and abs(value) >= 10 ** 20 else f"{value:g}"


def describe(value: object) -> str:
    """A value as the TOML reader sees it, for 'got ...' in messages."""
    if isinstance(value, bool):
        return f"{str(value).lower()} (a boolean)"
    if isinstance(value, str):
        return f"the string {show(value)}"
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "an array"
    if isinstance(value, (datetime.date, datetime.time)):
        return f"the date/time {value.isoformat()}"
    return show(value)


def suggest(word: str, choices: Iterable[str]) -> str:
    """' (did you mean 'x'?)' for a close match, else ' (known: a, b, c)'."""
    choices = list(choices)
    same = [c for c in choices if c.lower() == str(word).lower()]
    if same:
        return f" (did you mean {same[0]!r}?)"
    close = difflib.get_close_matches(str(word), choices, n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(choices)})"


def is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _allowed(key: str, gt: float | None, ge: float | None, le: float | None, unit: str) -> str:
    """' (allowed: 0 < dwell_s <= 86400 s)': the range of `key` for its messages."""
    low = f"{ge:g} <= " if ge is not None else f"{gt:g} < " if gt is not None else ""
    high = f" <= {le:g}" if le is not None else ""
    if not (low or high):
        return ""
    return f" (allowed: {low}{key}{high}{' ' + unit if unit else ''})"


class Located:
    """The document-wide context: its name, line map and the folder relative paths start from."""

    def __init__(self, source: str, lines: LineMap, base_dir: Path):
        self.source, self.lines, self.base_dir = source, lines, base_dir

    def error(self, path: tuple, message: str) -> ConfigError:
        return ConfigError(self.source, self.lines.line(*path), dotted(path), message)


class Table:
    """One table of the document; unknown keys are rejected on construction."""

    def __init__(self, doc: Located, path: tuple, data: dict, allowed: Iterable[str]):
        self.doc, self.path, self.data, self.allowed = doc, path, data, tuple(allowed)
        for key in data:
            if key not in self.allowed:
                raise doc.error(path + (key,), "unknown key" + suggest(key, self.allowed))

    def error(self, key, message: str) -> ConfigError:
        return self.doc.error(self.path + ((key,) if key is not None else ()), message)

    def has(self, key: str) -> bool:
        return key in self.data

    def get(self, key: str, default: Any = _REQUIRED) -> Any:
        if key in self.data:
            return self.data[key]
        if default is _REQUIRED:
            raise self.error(key, "missing required key")
        return default

    @overload
    def number(self, key: str, default: float | _Required = _REQUIRED, *, gt: float | None = None,
               ge: float | None = None, le: float | None = None, unit: str = "") -> float: ...

    @overload
    def number(self, key: str, default: None, *, gt: float | None = None, ge: float | None = None,
               le: float | None = None, unit: str = "") -> float | None: ...

    def number(self, key: str, default: float | None | _Required = _REQUIRED, *, gt: float | None = None,
               ge: float | None = None, le: float | None = None, unit: str = "") -> float | None:
        """A finite number (an int is taken as a float) within the bounds; `default` when the
        key is absent. A value beyond a bound gets "must be <= 86400 s, got 1e+308" (the bound
        it broke), a value of the wrong type the whole range. With both `gt` and `ge` the range
        is `ge`..`le`, `gt` only chooses the message at or below it ("must be > 0 Hz" for 0)."""
        value = self.get(key, default)
        if key not in self.data:
            return value
        allowed = _allowed(key, gt, ge, le, unit)
        # Bounds are compared before any float(): a 400-digit integer compares exactly.
        if not is_number(value) or (isinstance(value, float) and not math.isfinite(value)):
            raise self.error(key, f"must be a finite number, got {describe(value)}{allowed}")
        unit = f" {unit}" if unit else ""
        for bound, ok, op in ((gt, gt is None or value > gt, ">"), (ge, ge is None or value >= ge, ">="),
                              (le, le is None or value <= le, "<=")):
            if not ok:
                assert bound is not None
                raise self.error(key, f"must be {op} {bound:g}{unit}, got {number_text(value)}")
        if isinstance(value, int) and abs(value) >= 2 ** 1023:  # unbounded and beyond any float
            raise self.error(key, f"must be a finite number, got {show(value)}{allowed}")
        return float(value)

    @overload
    def integer(self, key: str, default: int | _Required = _REQUIRED, *, ge: int | None = None,
                le: int | None = None) -> int: ...

    @overload
    def integer(self, key: str, default: None, *, ge: int | None = None, le: int | None = None) -> int | None: ...

    def integer(self, key: str, default: int | None | _Required = _REQUIRED, *, ge: int | None = None,
                le: int | None = None) -> int | None:
        """A whole number (not a boolean) within the bounds; `default` when the key is absent."""
        value = self.get(key, default)
        if key not in self.data:
            return value
        allowed = _allowed(key, None, ge, le, "")
        if not isinstance(value, int) or isinstance(value, bool):
            raise self.error(key, f"must be a whole number, got {describe(value)}{allowed}")
        for bound, ok, op in ((ge, ge is None or value >= ge, ">="), (le, le is None or value <= le, "<=")):
            if not ok:
                raise self.error(key, f"must be {op} {bound}, got {show(value)}")
        return value

    def boolean(self, key: str, default=_REQUIRED) -> bool:
        value = self.get(key, default)
        if not isinstance(value, bool):
            raise self.error(key, f"must be true or false, got {describe(value)}")
        return value

    def string(self, key: str, default=_REQUIRED, *, choices: Iterable[str] | None = None,
               nonempty: bool = False) -> str:
        value = self.get(key, default)
        if not isinstance(value, str):
            raise self.error(key, f"must be a string, got {describe(value)}")
        if nonempty and not value.strip():
            raise self.error(key, "must not be empty")
        if choices is not None and value not in choices:
            choices = list(choices)
            raise self.error(key, f"got {show(value)}, expected one of {', '.join(choices)}")
        return value

    def file(self, key: str) -> Path:
        """A path value; relative paths start at the configuration file's folder."""
        return self.resolve(key, self.string(key, nonempty=True))

    def path_value(self, key: str, name: str) -> Path:
        """`name` (the value of `key`) as a path with ``~`` expanded, as written otherwise."""
        if "\0" in name:
            raise self.error(key, f"must not contain a NUL character, got {describe(name)}")
        try:
            return Path(name).expanduser()
        except RuntimeError as exc:  # ~user that does not exist, no home directory
            raise self.error(key, f"cannot expand {show(name)}: {exc}") from None

    def resolve(self, key: str, name: str) -> Path:
        """`name` (the value of `key`) as a path; relative paths start at the configuration file's folder."""
        path = self.path_value(key, name)
        return path if path.is_absolute() else self.doc.base_dir / path

    def is_file(self, key: str, path: Path) -> bool:
        """`path.is_file()`, a path the system refuses (too long, ...) reported at `key`."""
        try:
            return path.is_file()
        except OSError as exc:
            raise self.error(key, f"cannot use the path {show(str(path))}: {exc.strerror or exc}") from None

    def table(self, key: str, allowed: Iterable[str], required: bool = False) -> "Table":
        """A sub-table (empty when absent and not required)."""
        if required and key not in self.data:
            raise self.error(key, f"missing required table [{dotted(self.path + (key,))}]")
        value = self.data.get(key, {})
        if not isinstance(value, dict):
            raise self.error(key, f"must be a table ([{dotted(self.path + (key,))}]), got {describe(value)}")
        return Table(self.doc, self.path + (key,), value, allowed)
