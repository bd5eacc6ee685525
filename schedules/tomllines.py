"""Where each key of a TOML document is written: key paths -> 1-based line numbers.

`tomllib` reports no positions for parsed values, so errors found while validating a
document would otherwise say only *what* is wrong, not *where*. `locate_lines` scans
the raw text once and records the line of every table header, key (dotted, quoted,
inside inline tables) and array element, keyed by the same path a reader uses to
reach the value: ``("table", "limits", "outer", "max_rate_dps")``,
``("position", 3, "angles_deg")`` for the 4th ``[[position]]`` table,
``("sim", "black_box_arcsec", 1)`` for the 2nd row of an array.

Run it only on text `tomllib` accepted: the scan trusts the syntax and, should it
still meet something it cannot follow, returns what it found so far (positions are a
nicety for error messages; they never make a valid document fail).
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterable

KeyPath = tuple  # of str keys and int array indices

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_SCALAR = re.compile(r"[^,\]\}#\r\n]*")  # numbers, booleans, dates: up to the next delimiter


class LineMap:
    """Key paths of one document mapped to the line where each is first written."""

    def __init__(self, lines: dict[KeyPath, int] | None = None):
        self.lines: dict[KeyPath, int] = dict(lines or {})

    def exact(self, *path) -> int | None:
        """The line of exactly this path, None if it is not written in the text."""
        return self.lines.get(tuple(path))

    def line(self, *path) -> int | None:
        """The line of `path`, else of its nearest written ancestor (a missing key
        points at its table header); None when nothing on the path is written."""
        path = tuple(path)
        while path:
            if path in self.lines:
                return self.lines[path]
            path = path[:-1]
        return None

    def __contains__(self, path) -> bool:
        return tuple(path) in self.lines

    def __repr__(self) -> str:
        return f"LineMap({len(self.lines)} paths)"


class _Stop(Exception):
    """The scan met something it cannot follow; keep what was found."""


class _Scanner:
    def __init__(self, text: str):
        self.s, self.i, self.line = text, 0, 1
        self.found: dict[KeyPath, int] = {}
        self.arrays: dict[KeyPath, int] = {}  # array-of-tables path -> tables seen so far

    # -- characters ---------------------------------------------------------------
    def ch(self, k: int = 0) -> str:
        j = self.i + k
        return self.s[j] if j < len(self.s) else ""

    def skip(self, n: int = 1) -> None:
        self.line += self.s.count("\n", self.i, self.i + n)
        self.i += n

    def skip_to(self, j: int) -> None:
        self.skip(j - self.i)

    def blanks(self) -> None:
        while self.ch() in (" ", "\t"):
            self.i += 1

    def blanks_lines_comments(self) -> None:
        while True:
            c = self.ch()
            if c in (" ", "\t", "\r", "\n"):
                self.skip()
            elif c == "#":
                end = self.s.find("\n", self.i)
                self.skip_to(len(self.s) if end < 0 else end)
            else:
                return

    def expect(self, token: str) -> None:
        if not self.s.startswith(token, self.i):
            raise _Stop
        self.skip(len(token))

    def mark(self, path: KeyPath, line: int) -> None:
        for k in range(1, len(path) + 1):
            self.found.setdefault(path[:k], line)

    # -- keys and strings ---------------------------------------------------------
    def string_end(self) -> int:
        """Index just past the string starting at `i` (any of the four kinds)."""
        s, i = self.s, self.i
        for quote in ('"""', "'''"):
            if s.startswith(quote, i):
                j = i + 3
                while True:
                    if quote[0] == '"' and s[j] == "\\":
                        j += 2
                    elif s.startswith(quote, j):
                        extra = 0  # up to two quotes may end the content: """a"""" is 'a"'
                        while extra < 2 and s.startswith(quote[0], j + 3 + extra):
                            extra += 1
                        return j + 3 + extra
                    else:
                        j += 1
        j = i + 1
        if s[i] == "'":
            return s.index("'", j) + 1
        while s[j] != '"':
            j += 2 if s[j] == "\\" else 1
        return j + 1

    def key(self) -> tuple[str, ...]:
        parts = []
        while True:
            self.blanks()
            if self.ch() in ('"', "'"):
                end = self.string_end()
                token = self.s[self.i:end]
                # Let tomllib undo escapes: the key then matches the parsed document.
                parts.append(next(iter(tomllib.loads(f"{token} = 0"))))
                self.skip_to(end)
            else:
                match = _BARE_KEY.match(self.s, self.i)
                if match is None:
                    raise _Stop
                parts.append(match.group())
                self.skip_to(match.end())
            self.blanks()
            if self.ch() != ".":
                return tuple(parts)
            self.skip()

    # -- values -------------------------------------------------------------------
    def value(self, path: KeyPath) -> None:
        c = self.ch()
        if c in ('"', "'"):
            self.skip_to(self.string_end())
        elif c == "{":
            self.skip()
            self.blanks()
            if self.ch() == "}":
                self.skip()
                return
            while True:
                self.blanks()
                line = self.line
                sub = path + self.key()
                self.expect("=")
                self.blanks()
                self.mark(sub, line)
                self.value(sub)
                self.blanks()
                if self.ch() == ",":
                    self.skip()
                    continue
                self.expect("}")
                return
        elif c == "[":
            self.skip()
            index = 0
            while True:
                self.blanks_lines_comments()
                if self.ch() == "]":
                    self.skip()
                    return
                self.mark(path + (index,), self.line)
                self.value(path + (index,))
                self.blanks_lines_comments()
                if self.ch() == ",":
                    self.skip()
                    index += 1
                    continue
                self.expect("]")
                return
        else:
            match = _SCALAR.match(self.s, self.i)
            assert match is not None  # the pattern is `[...]*`: it matches the empty string anywhere
            if not match.group().strip():
                raise _Stop
            self.skip_to(match.end())

    # -- statements ---------------------------------------------------------------
    def header_path(self, parts: tuple[str, ...], array: bool) -> KeyPath:
        """Resolve a header: parents that are arrays of tables mean their last table."""
        path: KeyPath = ()
        for k, part in enumerate(parts):
            path += (part,)
            last = k == len(parts) - 1
            if last and array:
                count = self.arrays.get(path, 0) + 1
                self.arrays[path] = count
                path += (count - 1,)
            elif path in self.arrays:
                path += (self.arrays[path] - 1,)
        return path

    def run(self) -> dict[KeyPath, int]:
        table: KeyPath = ()
        while True:
            self.blanks_lines_comments()
            if self.i >= len(self.s):
                return self.found
            line = self.line
            if self.s.startswith("[[", self.i):
                self.skip(2)
                table = self.header_path(self.key(), array=True)
                self.expect("]]")
                self.mark(table, line)
            elif self.ch() == "[":
                self.skip()
                table = self.header_path(self.key(), array=False)
                self.expect("]")
                self.mark(table, line)
            else:
                path = table + self.key()
                self.expect("=")
                self.blanks()
                self.mark(path, line)
                self.value(path)


def locate_lines(text: str) -> LineMap:
    """Map every key path of TOML `text` (accepted by tomllib) to its 1-based line."""
    scanner = _Scanner(text)
    try:
        scanner.run()
    except (_Stop, IndexError, ValueError, tomllib.TOMLDecodeError):
        pass  # keep the lines found so far
    return LineMap(scanner.found)


def leaf_paths(doc: dict | list, prefix: KeyPath = ()) -> Iterable[KeyPath]:
    """Every path from the root of a parsed document to a scalar (test helper, debugging)."""
    items = doc.items() if isinstance(doc, dict) else enumerate(doc)
    for key, value in items:
        if isinstance(value, (dict, list)) and value:
            yield from leaf_paths(value, prefix + (key,))
        else:
            yield prefix + (key,)
