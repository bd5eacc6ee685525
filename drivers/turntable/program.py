"""A program message's units: the split both line dialects' codecs share (`scpi_codec`, `acutrol_codec`)."""

from __future__ import annotations


def split_program_units(text: str) -> tuple[list[str], bool]:
    """`text` split at every ';' outside a double-quoted string: (the units, empty ones kept; whether a string
    was left open at the end)."""
    units: list[str] = []
    current: list[str] = []
    quoted = False
    for char in text:
        if char == '"':
            quoted = not quoted
        if char == ";" and not quoted:
            units.append("".join(current))
            current = []
        else:
            current.append(char)
    units.append("".join(current))
    return units, quoted


__all__ = ["split_program_units"]
