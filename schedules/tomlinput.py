"""Bounded TOML input, shared by the schedule loader and the bench configuration reader.

A bad input file must end in one located error line, never a traceback or a machine
out of memory. Limits:

- a file is read only when it is a regular file (not a directory, device, FIFO or
  socket: ``/dev/zero`` would never end) of at most `MAX_FILE_BYTES` (1 MiB);
- arrays and inline tables nest at most `MAX_NESTING` (32) levels deep (`tomllib`
  recurses per level and would raise `RecursionError` at a few hundred);
- an integer has at most 4300 digits (Python's int-from-string limit, which `tomllib`
  hits with a bare `ValueError`).

`read_text_file` and `loads` raise `InputLimitError` (with the line where known) for
these, `OSError`/`UnicodeDecodeError` for an unreadable file and
`tomllib.TOMLDecodeError` for a syntax error; the callers turn each into their own
one-line error.
"""

from __future__ import annotations

import errno
import os
import re
import stat
import sys
import tomllib
from pathlib import Path

MAX_FILE_BYTES = 1 << 20      # 1 MiB: the shipped schedules are < 16 kB, a configuration < 12 kB
MAX_NESTING = 32              # arrays and inline tables; the formats here need 2

_KINDS = ((stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"), (stat.S_ISFIFO, "a FIFO"),
          (stat.S_ISSOCK, "a socket"))


class InputLimitError(ValueError):
    """A file or document beyond the input limits; `line` (1-based) where it is known."""

    def __init__(self, message: str, line: int | None = None):
        self.message, self.line = message, line
        super().__init__(message)


def read_text_file(path: str | Path, max_bytes: int = MAX_FILE_BYTES) -> str:
    """The UTF-8 text of the regular file `path`, at most `max_bytes` long.

    Opened without blocking (a FIFO without a writer would wait forever) and checked on the
    open descriptor; at most `max_bytes` + 1 bytes are ever read.
    """
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with os.fdopen(fd, "rb") as file:
        mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), str(path))
        if not stat.S_ISREG(mode):
            what = next((name for test, name in _KINDS if test(mode)), "a special file")
            raise InputLimitError(f"not a regular file ({what})")
        data = file.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputLimitError(f"larger than the {_size(max_bytes)} limit for input files")
    return data.decode("utf-8")


def _size(n: int) -> str:
    return f"{n >> 20} MiB" if n % (1 << 20) == 0 else f"{n} bytes"


# One token of interest outside strings and comments (the order of the alternatives matters).
_TOKEN = re.compile(r'"""|\'\'\'|["\'#\[\]{}\n]')
_BASIC_END = re.compile(r'(?:[^"\\\n]|\\.)*"')           # rest of a "..." string
_ML_BASIC_END = re.compile(r'(?:[^\\]|\\.)*?"""', re.S)  # rest of a """...""" string
_MAX_DIGITS = sys.get_int_max_str_digits() or 4300
_LONG_INTEGER = re.compile(r"[0-9][0-9_]{%d,}" % _MAX_DIGITS)


def _brackets(text: str):
    """(bracket, line) of every `[ ] { }` outside strings and comments, in order.

    A light scan; on text it cannot follow (an unterminated string) it stops: `tomllib` then
    reports the syntax error.
    """
    line, i, n = 1, 0, len(text)
    while i < n:
        match = _TOKEN.search(text, i)
        if match is None:
            return
        token, i = match.group(), match.end()
        if token == "\n":
            line += 1
        elif token == "#":
            end = text.find("\n", i)
            i = n if end < 0 else end
        elif token in ('"""', "'''"):
            if token == '"""':
                found = _ML_BASIC_END.match(text, i)
                end = found.end() if found else -1
            else:
                end = text.find("'''", i)
                end = end + 3 if end >= 0 else -1
            if end < 0:
                return
            line += text.count("\n", i, end)
            i = end
        elif token == '"':
            found = _BASIC_END.match(text, i)
            if found is None:
                return
            i = found.end()
        elif token == "'":
            end = text.find("'", i)
            if end < 0 or "\n" in text[i:end]:
                return
            i = end + 1
        else:
            yield token, line


def nesting_error_line(text: str, max_depth: int = MAX_NESTING) -> int | None:
    """The line where arrays/inline tables first nest deeper than `max_depth`, else None."""
    depth = 0
    for token, line in _brackets(text):
        if token in "[{":
            depth += 1
            if depth > max_depth:
                return line
        else:  # "]" or "}"
            depth = max(depth - 1, 0)
    return None


_TOML_LOCATION = re.compile(r"\s*\(at line (\d+), column (\d+)\)")
_UNCLOSED = {"Unclosed array": "[", "Unclosed inline table": "{"}


def syntax_error_location(text: str, exc: tomllib.TOMLDecodeError) -> tuple[int, str]:
    """(line, message) of a TOML syntax error for a one-line report.

    tomllib reports an unclosed array or inline table where it noticed it (often the next
    line); the line of the bracket left open is the one to fix, so that one is given."""
    message = str(exc)
    found = _TOML_LOCATION.search(message)
    if found is None:  # "(at end of document)"
        return max(len(text.splitlines()), 1), f"invalid TOML: {message}"
    line, column = int(found.group(1)), found.group(2)
    message = _TOML_LOCATION.sub("", message)
    opener = _UNCLOSED.get(message)
    if opener is not None:
        stack = []
        for token, at in _brackets(text):
            if at >= line:
                break
            if token in "[{":
                stack.append((token, at))
            elif stack:
                stack.pop()
        opened = [at for token, at in stack if token == opener]
        if opened:
            return opened[-1], f"invalid TOML: {message}: the {opener} opened here is not closed"
    return line, f"invalid TOML: {message} (column {column})"


def loads(text: str, max_depth: int = MAX_NESTING) -> dict:
    """`tomllib.loads(text)` within the limits above (`InputLimitError` beyond them)."""
    line = nesting_error_line(text, max_depth)
    if line is not None:
        raise InputLimitError(f"arrays and inline tables nested more than {max_depth} levels deep", line)
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError:
        raise
    except RecursionError:  # pragma: no cover - the nesting check comes first
        raise InputLimitError("nested too deeply for the TOML reader") from None
    except ValueError:  # int("<more than 4300 digits>") inside tomllib
        found = _LONG_INTEGER.search(text)
        raise InputLimitError(f"an integer with more than {_MAX_DIGITS} digits",
                              None if found is None else text.count("\n", 0, found.start()) + 1) from None
