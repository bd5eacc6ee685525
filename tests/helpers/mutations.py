"""Random mutations of TOML input files, for the configuration and schedule fuzzing.

`mutate(text, rnd)` applies a few random edits to a configuration or schedule file and
returns the bytes to write: lines deleted, duplicated, swapped or uncommented, values
replaced with huge, tiny, NaN, negative or 400-digit numbers, long strings, deeply
nested arrays or inline tables, wrong types and special paths, random bytes inserted,
the file cut short. `rnd` is a `random.Random`: the suite's fuzz test
(tests/unit/config/test_config_fuzz.py) passes hypothesis' `st.randoms()`, the command-line fuzzer
(fuzz/cli_fuzz.py) a seeded one.
"""

from __future__ import annotations

import random
import re

_DIGITS_400 = "1" + "0" * 399
#: Replacement values, as TOML source text, by what they stand in for.
NUMBERS = (  # huge, tiny, not finite, negative, zero, long
    "1e308", "-1e308", "1.7976931348623157e308", "1e-300", "5e-324", "-1e-300", "nan", "+inf", "-inf",
    "-1", "0", "-0.0", "1", "2", "0.5", "360", "359.999", "-90", "1e12", "4294967296", "86401", "1e6",
    "9223372036854775807", "-9223372036854775808", _DIGITS_400, "-" + _DIGITS_400, "0x7fffffff", "1_000_000",
)
STRINGS = (  # names and paths the readers open or look up
    '"/dev/zero"', '"/dev/null"', '"/dev/urandom"', '"/"', '"."', '"~nosuchuser-fuzz/x.toml"', '"\\u0000"',
    '"a\\u0000b"', '"' + "x" * 5000 + '"', '"' + "y" * 100_000 + '"', '"optimal-24"', '"optimal-5s6r"',
    '"table-check-324"', '"\\n\\t\\r"', "'''multi\nline'''", '""', '"   "', '"text"',
)
ARRAYS = (  # angle triples, rows, nesting
    "[0, 0, " + _DIGITS_400 + "]", "[0, nan, 0]", "[0, 90, inf]", "[-90, 0, 0]", "[0, 0, 360]", "[0, 0, 1e308]",
    "[0, 45, 0]", "[12.5, 0, 359.9]", "[true, 0, 0]", '["0", 0, 0]', "[]", "[1, 2, 3]", "[0, 0]",
    "[[1, 2, 3], [4, 5, 6]]", "[[1e308, 0, 0], [0, 0, 0], [0, 0, 0]]", "[" * 5000 + "]" * 5000,
    "[" * 200 + "]" * 200, "[" * 40 + "1" + "]" * 40, "{a=" * 3000 + "1" + "}" * 3000, "{a=" * 60 + "1" + "}" * 60,
)
OTHERS = ("true", "false", "{}", "{ a = 1 }", "1979-05-27T07:32:00Z", "1979-05-27", "07:32:00")
VALUES = NUMBERS + STRINGS + ARRAYS + OTHERS
#: Edits, repeated by weight: mostly value replacements, so that many files get past the syntax.
_OPS = ("value",) * 8 + ("uncomment",) * 3 + ("delete",) * 2 + ("duplicate", "swap", "header", "key", "bytes",
                                                                 "truncate", "nest")
_BYTES = b"\x00\xff\xfe\x80\r\n\t\"'[]{}=#.,\\ \x1b\xe9"
_ASSIGNMENT = re.compile(r"^(\s*)([A-Za-z0-9_\"'.-]+)(\s*=\s*)(.*?)(\s*(#.*)?)$")
_COMMENTED = re.compile(r"^#\s?(\s*[A-Za-z0-9_.\"'-]+\s*=\s*[-+0-9\"'\[{tf].*)$")  # not prose with a '='
_COMMENTED_HEADER = re.compile(r"^#\s?(\[[A-Za-z0-9_.]+\].*)$")


def _value(rnd: random.Random, old: str) -> str:
    """A replacement for the value written `old`: mostly one of its own sort (a number for a
    number, ...) or the old number scaled, sometimes anything from `VALUES`."""
    if rnd.random() < 0.25:
        return rnd.choice(VALUES)
    if old.startswith(("[", "{")):
        return rnd.choice(ARRAYS)
    if old.startswith(("\"", "'")):
        return rnd.choice(STRINGS)
    try:
        number = float(old.replace("_", ""))
    except ValueError:
        return rnd.choice(VALUES)
    if rnd.random() < 0.35:
        return repr(number * rnd.choice((-1, 1e-300, 1e-6, 10, 1e6, 1e300)) + rnd.choice((0, 1, -1)))
    return rnd.choice(NUMBERS)


def _assignments(lines: list[str]) -> list[int]:
    return [i for i, line in enumerate(lines) if not line.lstrip().startswith("#") and _ASSIGNMENT.match(line)]


def _one(lines: list[str], rnd: random.Random) -> list[str]:
    """`lines` after one random edit (lines without their line ends)."""
    if not lines:
        return [rnd.choice(VALUES)]
    op = rnd.choice(_OPS)
    i = rnd.randrange(len(lines))
    if op == "delete":
        del lines[i]
    elif op == "duplicate":
        lines.insert(rnd.randrange(len(lines) + 1), lines[i])
    elif op == "swap":
        j = rnd.randrange(len(lines))
        lines[i], lines[j] = lines[j], lines[i]
    elif op in ("value", "key"):
        found = _assignments(lines)
        if op == "value" and rnd.random() < 0.3:  # a commented-out key, uncommented with its new value
            commented = [k for k, line in enumerate(lines) if _COMMENTED.match(line)]
            if commented:
                k = rnd.choice(commented)
                match = _COMMENTED.match(lines[k])
                assert match is not None
                lines[k] = match.group(1)
                found = [k] if _ASSIGNMENT.match(lines[k]) else found
        if found:
            i = rnd.choice(found)
            match = _ASSIGNMENT.match(lines[i])
            assert match is not None
            indent, key, eq, value, comment = match.group(1, 2, 3, 4, 5)
            if op == "value":
                value = _value(rnd, value)
            else:  # another key of the file (a duplicate or a misplaced key), or a typo
                keys = [m.group(2) for m in map(_ASSIGNMENT.match, lines) if m]
                key = rnd.choice(keys) if rnd.random() < 0.7 else key + rnd.choice(("s", "_x", ".y", ""))
            lines[i] = f"{indent}{key}{eq}{value}{comment or ''}"
    elif op == "uncomment":  # a commented-out key, or a commented-out table with the keys below it
        found = [k for k, line in enumerate(lines) if _COMMENTED.match(line) or _COMMENTED_HEADER.match(line)]
        if found:
            k = rnd.choice(found)
            header = _COMMENTED_HEADER.match(lines[k])
            if header is not None:
                lines[k] = header.group(1)
                k += 1
            while k < len(lines) and (match := _COMMENTED.match(lines[k])):
                lines[k] = match.group(1)
                k += 1
                if header is None:
                    break
    elif op == "header":
        headers = [k for k, line in enumerate(lines) if line.startswith("[")]
        if headers:
            k = rnd.choice(headers)
            lines[k] = rnd.choice((lines[k].replace("[", "[[", 1).replace("]", "]]", 1),
                                   lines[k].replace("[[", "[", 1).replace("]]", "]", 1),
                                   lines[k].rstrip("]") + ".sub]", "[" + "a." * 2000 + "b]"))
    elif op == "bytes":
        text = lines[i]
        at = rnd.randrange(len(text) + 1)
        junk = bytes(rnd.choice(_BYTES) for _ in range(rnd.randint(1, 6)))
        lines[i] = text[:at] + junk.decode("latin-1") + text[at:]  # re-encoded byte for byte below
    elif op == "truncate":
        del lines[i:]
        if lines and rnd.random() < 0.5:
            lines[-1] = lines[-1][: rnd.randrange(len(lines[-1]) + 1)]
    else:  # "nest": a deeply nested value on a new line
        depth = rnd.choice((40, 300, 1100, 5000))
        open_, close = rnd.choice((("[", "]"), ("{a=", "}")))
        lines.insert(i, f"deep_{i} = {open_ * depth}{'1' if open_ != '[' else ''}{close * depth}")
    return lines


def mutate(text: str, rnd: random.Random, max_edits: int = 4) -> bytes:
    """`text` after 1..`max_edits` random edits (one edit in most cases), as bytes (random bytes may
    make it invalid UTF-8)."""
    lines = text.splitlines()
    for _ in range(1 if rnd.random() < 0.6 else rnd.randint(2, max_edits)):
        lines = _one(lines, rnd)
    out = "\n".join(lines) + ("\n" if rnd.random() < 0.9 else "")
    # Lines hold str; the random bytes were decoded as latin-1: encode those chars back to single
    # bytes and everything else (the original text, the values) as UTF-8.
    if not any("\x80" <= ch <= "\xff" for ch in set(out) - set(text)):
        return out.encode("utf-8")
    return b"".join(ch.encode("latin-1") if "\x80" <= ch <= "\xff" and ch not in text else ch.encode("utf-8")
                    for ch in out)
