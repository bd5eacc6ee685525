"""The certificates' error root: `CertError`, under `BenchError`."""

from __future__ import annotations

from bench.errors import BenchError


class CertError(BenchError):
    """A certificate cannot be issued or checked: a log that is not the run's, a file that is not a certificate,
    or one that disagrees with the records."""


__all__ = ["CertError"]
