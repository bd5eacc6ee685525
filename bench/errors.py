"""The bench's exception root.

Every error the bench raises on purpose derives from `BenchError`, raised `from` its
cause; a command line turns it (and the drivers' `DeviceError`)
into one line and an exit code, and lets anything else raise: an exception that is
not a `BenchError` is a bug and deserves its traceback.

`InputError` is the common kind: a value from the user, a configuration, a schedule,
a result file or a log that the bench cannot use. It is also a `ValueError`, as the
errors below it always were.
"""

from __future__ import annotations


class BenchError(Exception):
    """Base of every error the bench raises on purpose."""


class InputError(BenchError, ValueError):
    """A value from the user or from a file that the bench cannot use."""


__all__ = ["BenchError", "InputError"]
