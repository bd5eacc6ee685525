"""`bench`'s edge for I/O (issue 13 item 9): an OSError is one line and exit 2, a closed stdout a quiet exit 141.

In-process (tests/helpers/run.py `cli`) for the OSError cases; subprocesses whose stdout
is a pipe the reader has closed for the BrokenPipe cases: closed before the command
writes anything (deterministic for any output size), or after reading one line of an
output larger than the (shrunk) pipe holds, so the command is still writing when it closes.
Both with and without PYTHONUNBUFFERED: buffered, the error comes from the final flush.
"""

from __future__ import annotations

import fcntl
import os
import select
import subprocess
import sys
from pathlib import Path

import pytest

import bench.cli.evaluate
import bench.schedule_design.search
from bench.cli.main import EXIT_BROKEN_PIPE, main
from tests.helpers.run import REPO, cli, config_text, only_file

TIMEOUT_S = 120


def _one_line(rc: int, stdout: str, stderr: str, prefix: str) -> str:
    assert rc == 2, (rc, stdout, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(prefix + ": "), stderr
    assert "Traceback" not in stderr
    return lines[0]


# -- OSError -> one line, exit 2 ------------------------------------------------------------

def test_evaluate_json_into_a_missing_folder_is_one_line_before_the_work(tmp_path):
    target = tmp_path / "missing" / "x.json"
    rc, stdout, stderr = cli(["evaluate", "--runs", "2", "--json", str(target)])
    line = _one_line(rc, stdout, stderr, "bench evaluate")
    assert str(target) in line and "does not exist" in line
    assert stdout == ""                       # refused before the Monte Carlo, not after it
    rc, stdout, stderr = cli(["evaluate", "--runs", "2", "--json", str(tmp_path)])
    assert "is a folder" in _one_line(rc, stdout, stderr, "bench evaluate")


def test_schedules_search_out_an_existing_file_fails_before_the_search(tmp_path, monkeypatch):
    def no_search(*args, **kwargs):
        raise AssertionError("searched before checking --out")

    monkeypatch.setattr(bench.schedule_design.search, "search_positions", no_search)
    existing = tmp_path / "results"
    existing.write_text("not a folder\n", encoding="utf-8")
    rc, stdout, stderr = cli(["schedules", "search", "--out", str(existing), "--groups", "14", "--choose", "6"])
    line = _one_line(rc, stdout, stderr, "bench schedules search")
    assert str(existing) in line and "it is a file, not a folder" in line
    assert existing.read_text(encoding="utf-8") == "not a folder\n"


@pytest.mark.parametrize("error, needle", [
    (PermissionError(13, "Permission denied", "/data/out.json"), "/data/out.json: Permission denied"),
    (OSError(28, "No space left on device", "/data/run.mcap"), "/data/run.mcap: No space left on device"),
    (FileExistsError(17, "File exists", "/a", None, "/b"), "/a -> /b: File exists"),
    (OSError("something failed"), "something failed"),
    # a BrokenPipeError that is not stdout's (a socket, a FIFO) is an I/O error like any other
    (BrokenPipeError(32, "Broken pipe"), "Broken pipe"),
])
def test_an_os_error_escaping_any_command_is_one_line_and_exit_2(error, needle, monkeypatch, capsys):
    def raises(args):
        raise error

    monkeypatch.setattr(bench.cli.evaluate, "cmd_evaluate", raises)
    assert main(["evaluate"]) == 2
    captured = capsys.readouterr()
    line = _one_line(2, captured.out, captured.err, "bench evaluate")
    assert line.endswith(needle), line


# -- stdout closed by its reader -> quiet, exit 141 ------------------------------------------

def _env(buffered: bool) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    if not buffered:
        env["PYTHONUNBUFFERED"] = "1"
    return env


def _run_into_closed_pipe(args: list[str], buffered: bool) -> subprocess.CompletedProcess:
    """`bench ARGS` with stdout a pipe whose read end is closed before it starts."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    try:
        return subprocess.run([sys.executable, "-m", "bench.cli", *args], cwd=REPO, stdout=write_end,
                              stderr=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True, timeout=TIMEOUT_S,
                              env=_env(buffered))
    finally:
        os.close(write_end)


@pytest.fixture(scope="module")
def check_log(tmp_path_factory) -> Path:
    """A short simulated table check's log (16 positions, 3 s dwells) for `bench check-table --log`."""
    folder = tmp_path_factory.mktemp("check")
    lines = ['format = "turntable-bench/schedule"', "version = 1", 'name = "table-check-16"',
             'kind = "table-check"', 'description = "short table check for tests"', ""]
    for o in (0, 90, 180, 270):
        for i in (45, 135, 225, 315):
            lines += ["[[position]]", f"angles_deg = [{o}, 0, {i}]", ""]
    schedule = folder / "table-check-16.toml"
    schedule.write_text("\n".join(lines), encoding="utf-8")
    config = folder / "bench.toml"
    config.write_text(config_text(black_box_arcsec=20.0), encoding="utf-8")
    rc, _, stderr = cli(["check-table", "--config", str(config), "--schedule", str(schedule), "--dwell-s", "3",
                         "--out", str(folder / "out"), "--quiet"])
    assert rc == 0, stderr
    return only_file(folder / "out", "*.mcap")


@pytest.mark.slow
@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
@pytest.mark.parametrize("command", ["evaluate", "schedules-show", "check-table-log"])
def test_a_closed_stdout_is_a_quiet_exit_141(command, buffered, request, tmp_path):
    args = {"evaluate": ["evaluate", "--runs", "3"],
            "schedules-show": ["schedules", "show", "optimal-24"],
            "check-table-log": ["check-table", "--out", str(tmp_path), "--log"]}[command]
    if command == "check-table-log":
        args.append(str(request.getfixturevalue("check_log")))
    done = _run_into_closed_pipe(args, buffered)
    assert done.stderr == ""                  # no traceback, no "Exception ignored in: <stdout>"
    assert done.returncode == EXIT_BROKEN_PIPE


@pytest.mark.slow
@pytest.mark.skipif(not hasattr(fcntl, "F_SETPIPE_SZ"), reason="needs Linux pipe sizes")
@pytest.mark.parametrize("buffered", [True, False], ids=["buffered", "unbuffered"])
def test_reading_one_line_then_closing_the_pipe_is_a_quiet_exit_141(buffered):
    # A pipe of one page (4096 bytes) and a 13.5 kB output, read one byte at a time up to the first
    # newline: when the reader closes, at least 9 kB are still to be written, however fast either side runs.
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)
    try:
        proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "schedules", "show", "table-check-324"],
                                cwd=REPO, stdout=write_end, stderr=subprocess.PIPE, stdin=subprocess.DEVNULL,
                                env=_env(buffered))
    finally:
        os.close(write_end)
    try:
        first = b""
        for _ in range(200):                       # the first line is ~25 bytes
            ready, _, _ = select.select([read_end], [], [], TIMEOUT_S)
            assert ready, "no output"
            byte = os.read(read_end, 1)
            first += byte
            if byte in (b"\n", b""):
                break
        assert first.startswith(b"name:") and first.endswith(b"\n"), first
        os.close(read_end)
        read_end = -1
        _, stderr = proc.communicate(timeout=TIMEOUT_S)
    finally:
        if read_end >= 0:
            os.close(read_end)
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
    assert stderr == b""
    assert proc.returncode == EXIT_BROKEN_PIPE
