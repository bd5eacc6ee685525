"""`bench tui` as a command (issue 19): the last run's log and exit code when it quits, --speed only with
--replay, no start without a terminal. Subprocesses are bounded by a timeout; no timing is asserted."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from bench.acceptance.limits import AcceptanceLimits
from bench.acceptance.quality import judged_failures
from bench.acceptance.verdict import judge
from bench.cli.common import ExitCode
from bench.cli.tui import NO_TERMINAL, exit_status
from bench.log.events import RunState
from bench.model.quality import link_lost_samples, texts
from bench.model.result import CalibrationResult
from bench.run.runner import RunOutcome
from bench.tui.session import RunEnd, run_end_of
from tests.helpers.run import REPO, config_text
from tests.helpers.tui import connected, dialog_open, make_app, press, run, start_plan, wait_until

#: generous: the command imports Textual and the bench core before it refuses (seconds on a loaded machine)
SUBPROCESS_TIMEOUT_S = 120.0


def _bench_tui(*args: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """`python -m bench.cli tui ...` with stdin from /dev/null and stdout a pipe: no terminal."""
    return subprocess.run([sys.executable, "-m", "bench.cli", "tui", *args], cwd=REPO, stdin=subprocess.DEVNULL,
                          capture_output=True, text=True, timeout=SUBPROCESS_TIMEOUT_S)


@pytest.mark.slow
def test_without_a_terminal_bench_tui_refuses_to_start(tmp_path):
    """It spun at 90-99 % CPU until killed; now one line, exit 2, and nothing written."""
    out = tmp_path / "out"
    done = _bench_tui("--sim", "--out", str(out), tmp_path=tmp_path)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip() == f"bench tui: {NO_TERMINAL}"
    assert done.stdout == ""
    assert not out.exists() or not any(out.iterdir())


@pytest.mark.slow
def test_speed_is_refused_without_replay(tmp_path):
    config = tmp_path / "bench.toml"
    config.write_text(config_text(), encoding="utf-8")
    for args in (["--sim", "--speed", "2"], ["--config", str(config), "--speed", "2"]):
        done = _bench_tui(*args, "--out", str(tmp_path / "out"), tmp_path=tmp_path)
        assert done.returncode == 2, done.stderr
        assert done.stderr.strip() == ("bench tui: --speed is for --replay LOG only: a live run, also on the "
                                       "simulator, runs in real time")


def _ended(end: RunEnd | None, stopped_by: str | None = None):
    return SimpleNamespace(stopped_by=stopped_by, session=SimpleNamespace(running=False, last_end=end))


@pytest.mark.parametrize("end, code, stream, line", [
    (None, ExitCode.OK, "", ""),
    (RunEnd("done", "", Path("/o/r.mcap")), ExitCode.OK, "out", "bench tui: last run done. Log: /o/r.mcap"),
    (RunEnd("quality", "quality check failed: 2 residual outliers", Path("/o/r.mcap")), ExitCode.QUALITY, "err",
     "bench tui: last run finished: quality check failed: 2 residual outliers. Log: /o/r.mcap"),
    (RunEnd("aborted", "the operator quit", Path("/o/r.mcap")), ExitCode.FAULT, "err",
     "bench tui: last run aborted (the operator quit); the table was stopped. Log: /o/r.mcap"),
    (RunEnd("aborted", "the operator quit", Path("/o/r.mcap"), "bench run --sim --resume /o/r.mcap --out /o"),
     ExitCode.FAULT, "err", "bench tui: last run aborted (the operator quit); the table was stopped. Log: /o/r.mcap "
                            "(continue with: bench run --sim --resume /o/r.mcap --out /o)"),
    (RunEnd("failed", "TurntableLimitError: middle: limit", Path("/o/r.mcap")), ExitCode.FAULT, "err",
     "bench tui: last run failed (TurntableLimitError: middle: limit); the table was stopped. Log: /o/r.mcap"),
])
def test_exit_status_is_the_last_runs_with_its_log(capsys, end, code, stream, line):
    assert exit_status(_ended(end)) == code
    captured = capsys.readouterr()
    assert (captured.out if stream == "out" else captured.err).strip() == line
    assert (captured.err if stream == "out" else captured.out) == ""


def test_a_stop_signal_says_where_the_log_is(capsys):
    assert exit_status(_ended(RunEnd("aborted", "the operator quit", Path("/o/r.mcap")), "SIGTERM")) == 3
    assert capsys.readouterr().err.strip() == ("bench tui: interrupted (SIGTERM); any run aborted, the table "
                                               "stopped. Log: /o/r.mcap")


@pytest.mark.slow
def test_abort_and_quit_exits_3_and_names_the_log(tmp_path, capsys):
    """'Abort and quit' exited 0 and printed nothing (issue 19)."""
    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=(100, 30)) as pilot:
            await connected(pilot)
            await start_plan(pilot)
            await press(pilot, "q")
            await dialog_open(pilot, "ConfirmScreen", "#yes")
            await press(pilot, "y")
            await wait_until(pilot, lambda: not app.is_running, "the app to exit")
        return app

    holder = []

    async def keep():
        holder.append(await body())
    run(keep)
    app = holder[0]
    capsys.readouterr()
    assert exit_status(app) == ExitCode.FAULT
    log = app.session.last_end.log_path
    assert log is not None and log.parent == tmp_path and log.suffix == ".mcap" and log.is_file()
    # (make_app's configuration is text, no file: the command says FILE; tests/tui/test_tui_trust.py runs a real one)
    assert capsys.readouterr().err.strip() == (f"bench tui: last run aborted (the operator quit); the table was "
                                               f"stopped. Log: {log} (continue with: bench run --config FILE "
                                               f"--resume {log} --out {tmp_path})")


def test_a_finished_run_ends_by_its_verdict_as_bench_run_says_it():
    """Issue 27: the TUI ended a run by its raw quality failures: "done" beside a failed acceptance limit, and
    "quality check failed" for lost samples a limit had judged acceptable."""
    limits = AcceptanceLimits(max_lost_samples=10)
    lost = [link_lost_samples("3 lost")]

    def outcome(verdict, failures=()):
        return RunOutcome(RunState.DONE, Path("/o/r.mcap"), result_path=Path("/o/r.result.json"),
                          failures=list(failures), verdict=verdict)

    judged = judge(CalibrationResult({}), limits, lost_samples=3, quality_failures=texts(judged_failures(lost, limits)))
    assert run_end_of(outcome(judged, texts(lost))) == ("done", "", "done; verdict PASS; result r.result.json")
    failing = judge(CalibrationResult({}), AcceptanceLimits(max_lost_samples=0), lost_samples=3)
    kind, reason, text = run_end_of(outcome(failing))
    assert kind == "quality" and text == reason == "verdict FAIL: acceptance limit: lost samples 3 > 0 samples"
    unchecked = judge(CalibrationResult({}), AcceptanceLimits())
    assert run_end_of(outcome(unchecked))[2] == "done; verdict NOT CHECKED; result r.result.json"
    assert run_end_of(outcome(None, ["x"]))[:2] == ("quality", "quality check failed: x")
