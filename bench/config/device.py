"""What a device section ([table], [chamber]) of a configuration shares: the simulated device's url and the
checked url and dialect."""

from __future__ import annotations

from typing import Callable, Mapping

from bench.config.reader import Table

#: a device url that means "the simulated device, served by the run itself (loopback, the configured dialect)"
SIM_URL = "sim"


def url_and_dialect(t: Table, section: str, dialects: Mapping[str, str], check_url_dialect: Callable[..., None],
                    unknown_dialect: Callable[[str], str],
                    implied: Callable[[str], str] | None = None) -> tuple[str, str]:
    """The url and dialect of `t`, the section called `section`: both required, unless `implied(url)` gives the
    dialect the url implies. A dialect not in `dialects` is an error on `dialect` worded by
    `unknown_dialect(name)`; a url that cannot carry the dialect (`check_url_dialect`, whose error is a
    ValueError) is an error on `url`. The simulated device's url carries any dialect."""
    url = t.string("url", nonempty=True).strip()
    if implied is None:
        dialect = t.string("dialect", nonempty=True).strip().lower()
    else:
        dialect = t.string("dialect", implied(url), nonempty=True).strip().lower()
    if dialect not in dialects:
        raise t.error("dialect", unknown_dialect(dialect))
    if url != SIM_URL:
        try:
            check_url_dialect(url, dialect, dialect_label=f"{section}.dialect")
        except ValueError as exc:
            raise t.error("url", str(exc)) from exc
    return url, dialect


__all__ = ["SIM_URL", "url_and_dialect"]
