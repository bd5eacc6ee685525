"""The records database's errors: one root, `RecordsError`, under `BenchError`."""

from __future__ import annotations

from bench.errors import BenchError


class RecordsError(BenchError):
    """The records database cannot be opened, read or written."""


class SchemaError(RecordsError):
    """A database this software cannot use: a newer schema, or not a records database."""


__all__ = ["RecordsError", "SchemaError"]
