"""The lab-operator TUI (Textual). Only this package imports Textual; `buffer` and `session` do not."""

from __future__ import annotations


def create_app(**kwargs):
    """The TUI app (see `bench.tui.app.create_app`); imports Textual only when called."""
    # local: bench.tui.app imports Textual (heavy); `buffer` and `session` are used without it
    from bench.tui.app import create_app as _create_app

    return _create_app(**kwargs)
