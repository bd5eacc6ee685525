"""A stop signal that comes while a module is being imported is delivered after the import, not inside it.

Inside an import an exception can come out as another one: numpy's compiled core, interrupted while it imports
`datetime`, reports an ImportError, and Ctrl-C during `bench run`'s start-up ended in that traceback."""

from __future__ import annotations

import signal
import sys
import time

import pytest

from bench.cli.edge import FirstSignal, Interrupted, stop_signals


def test_a_stop_signal_inside_an_import_is_raised_once_the_import_is_done(tmp_path, monkeypatch):
    (tmp_path / "probe_interrupted_import.py").write_text(
        "import signal\nsignal.raise_signal(signal.SIGINT)\nfinished = True\n", encoding="utf-8")
    monkeypatch.syspath_prepend(str(tmp_path))
    first = FirstSignal()
    with stop_signals(first), pytest.raises(Interrupted):
        import probe_interrupted_import  # noqa: F401
        for _ in range(10_000):         # bounded: the signal comes again within milliseconds
            time.sleep(0.001)
    assert first.signum == signal.SIGINT
    # the import was not cut short: the module ran to its end
    assert sys.modules["probe_interrupted_import"].finished is True
    monkeypatch.delitem(sys.modules, "probe_interrupted_import")


def test_a_stop_signal_outside_an_import_is_raised_where_it_comes():
    with stop_signals(FirstSignal()), pytest.raises(Interrupted):
        signal.raise_signal(signal.SIGINT)
        for _ in range(1_000):
            time.sleep(0.001)
        pytest.fail("the signal was not raised where it came")
