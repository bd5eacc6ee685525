"""The `[model]` section: which higher-order families the solve estimates beyond the 30 (`bench.model.extended`)."""

from __future__ import annotations

from bench.config.reader import Table
from bench.model.extended import TERMS

#: the `[model] terms` value that lets the data choose (`bench.solve.extended.AUTO`)
AUTO = "auto"


def model_terms(t: Table) -> tuple[str, ...]:
    """`[model] terms`: family names in the order given, or ("auto",); () for the 30 alone."""
    value = t.get("terms", [])
    choices = ", ".join((*TERMS, AUTO))
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise t.error("terms", f"must be a list of family names ({choices})")
    for name in value:
        if name not in TERMS and name != AUTO:
            raise t.error("terms", f"unknown family {name!r}: choose from {choices}")
        if value.count(name) > 1:
            raise t.error("terms", f"family {name!r} is listed twice")
    if AUTO in value and len(value) > 1:
        raise t.error("terms", f"{AUTO!r} stands alone (it chooses among all families)")
    return tuple(value)


__all__ = ["AUTO", "model_terms"]
