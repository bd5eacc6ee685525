"""`bench`'s backstop: known errors that escape a command become one line and an exit code; bugs raise."""

from __future__ import annotations

import pytest

import bench.cli.evaluate
from bench.cli.common import ExitCode
from bench.cli.main import main
from bench.errors import BenchError, InputError
from drivers.errors import ImuTimeout, TurntableConfigError, TurntableFault


@pytest.mark.parametrize("error, code", [
    (InputError("bad value"), ExitCode.USAGE),
    (BenchError("cannot"), ExitCode.USAGE),
    (TurntableConfigError("bad url"), ExitCode.USAGE),     # refused before anything was sent
    (TurntableFault("servo fault"), ExitCode.FAULT),
    (ImuTimeout("no frame"), ExitCode.FAULT),
])
def test_a_known_error_becomes_one_line_and_its_exit_code(error, code, monkeypatch, capsys):
    def raises(args):
        raise error

    monkeypatch.setattr(bench.cli.evaluate, "cmd_evaluate", raises)
    assert main(["evaluate"]) == code
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("bench evaluate: ") and str(error) in err


def test_a_bug_raises_with_its_traceback(monkeypatch):
    def raises(args):
        raise ValueError("a programming error")

    monkeypatch.setattr(bench.cli.evaluate, "cmd_evaluate", raises)
    with pytest.raises(ValueError, match="a programming error"):
        main(["evaluate"])
