"""Fail safe: every way a command that moves the table can end leaves the table stopped (issue 13).

A listener that fails (the recorder on a full disk, the progress output on a closed
pipe), SIGTERM and SIGHUP like Ctrl-C, an output folder that cannot be written.
Runs are the short simulated plan of tests/helpers/run.py, in-process or as
subprocesses (for signals and pipes); every wait is bounded.
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import signal
import struct
import subprocess
import sys
import termios
import threading

import numpy as np
import pytest

import bench.log.recorder as recorder_module
import bench.run.devices as devices_module
from bench.config.load import load_config
from bench.log.events import RunListener
from bench.log.reader import read_log
from bench.run.runner import BenchRun, compile_from_config
from drivers.turntable import AxisStatus
from tests.helpers.disk import FillingDisk
from tests.helpers.run import (
    AT_REST_DPS,
    REPO,
    Trigger,
    cli,
    config_text,
    only_file,
    start_cli,
    step_index,
    stop_process,
    transitions,
    wait_for,
)


class Capture(RunListener):
    def __init__(self):
        self.events = []

    def on_event(self, event):
        self.events.append(event)


@pytest.fixture
def config(tmp_path):
    path = tmp_path / "bench.toml"
    path.write_text(config_text(), encoding="utf-8")
    return path


# -- 1. a failing listener -----------------------------------------------------------------------

def test_a_full_log_disk_ends_the_run_exit_3_one_line_and_the_table_stopped(config, tmp_path, monkeypatch):
    monkeypatch.setattr(FillingDisk, "full", False)
    monkeypatch.setattr(recorder_module, "open", FillingDisk.open, raising=False)
    plan = compile_from_config(load_config(str(config)))
    dwell = step_index(plan, "dwell", 2)
    capture, at_close = Capture(), []
    original_open, original_close = BenchRun.open, BenchRun.close

    def open_and_fill_at_a_dwell(self):
        original_open(self)
        trigger = Trigger(dwell, lambda run: setattr(FillingDisk, "full", True))
        trigger.run = self
        self.extra_listeners += [trigger, capture]

    def close_seeing_the_table(self):
        if self.world is not None and not at_close:
            at_close.append(self.world.controller.state())
        original_close(self)

    monkeypatch.setattr(BenchRun, "open", open_and_fill_at_a_dwell)
    monkeypatch.setattr(BenchRun, "close", close_seeing_the_table)
    out = tmp_path / "out"
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(out), "--quiet"])
    assert rc == 3, stderr
    # one error line (with --quiet the progress output still shows the fault as it happens)
    lines = stderr.strip().splitlines()
    assert len(lines) == 2 and lines[0].startswith("FAULT: ") and lines[1].startswith("bench run: "), stderr
    log_path = only_file(out, "*.mcap")
    assert f"log disk full: cannot write MCAP log {log_path}: No space left on device" in stderr
    assert f"--resume {log_path}" in stderr
    assert not list(out.glob("*.result.json"))
    # the table: stopped and servos off before the devices closed
    assert at_close and all(not axis.enabled and abs(axis.rate_dps) < AT_REST_DPS for axis in at_close[0].axes)
    # the other listeners heard of it once, and of the stop
    faults = [e for e in capture.events if e.kind == "fault"]
    assert len(faults) == 1 and "log disk full" in faults[0].message
    assert transitions(capture.events)[-2:] == ["aborting", "failed"]
    assert any(e.kind == "info" and "servos off" in e.message for e in capture.events)
    # what reached the disk is a readable log cut short, like a crashed run's
    log = read_log(log_path)
    assert not log.summary_present and log.events and log.events[-1].time_s <= faults[0].time_s


def test_a_closed_progress_pipe_ends_the_run_exit_3_with_the_table_stopped(config, tmp_path):
    """`bench run ... 2>&1 | head -2`: the progress output's reader goes away mid-run."""
    out = tmp_path / "out"
    proc = start_cli("run", "--config", str(config), "--out", str(out))
    try:
        for _ in range(2):
            assert proc.stderr.readline()
        proc.stderr.close()
        proc.wait(timeout=60)
    finally:
        stop_process(proc)
    assert proc.returncode == 3
    log = read_log(only_file(out, "*.mcap"))
    assert log.summary_present and log.scan().complete, log.scan().damage
    faults = [e for e in log.events if e.kind == "fault"]
    assert len(faults) == 1 and "ProgressPrinter failed: BrokenPipeError" in faults[0].message
    assert transitions(log.events)[-2:] == ["aborting", "failed"]
    assert any(e.kind == "info" and "servos off" in e.message for e in log.events)
    assert np.abs(log.read_table_states().rates_dps[-1]).max() < AT_REST_DPS
    assert not list(out.glob("*.result.json"))


# -- 2. signals ----------------------------------------------------------------------------------

@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_sigterm_and_sighup_abort_bench_run_like_ctrl_c(signum, tmp_path):
    config_path = tmp_path / "bench.toml"
    # long dwells: the run must still be going when the signal comes, however fast the simulator gets
    config_path.write_text(config_text(dwell_s=20.0), encoding="utf-8")
    out = tmp_path / "out"
    proc = start_cli("run", "--config", str(config_path), "--out", str(out), "--quiet")
    try:
        log_path = wait_for(lambda: next((p for p in out.glob("*.mcap") if p.stat().st_size > 200_000), None),
                            60.0, "the log to pass 200 kB", proc=proc)
        proc.send_signal(signum)
        _, stderr = proc.communicate(timeout=60)
    finally:
        stop_process(proc)
    name = signal.Signals(signum).name
    assert proc.returncode == 3, stderr
    assert len(stderr.strip().splitlines()) == 1, stderr
    assert f"interrupted ({name})" in stderr and f"--resume {log_path}" in stderr
    log = read_log(log_path)
    assert log.summary_present and log.scan().complete, log.scan().damage
    assert np.abs(log.read_table_states().rates_dps[-1]).max() < AT_REST_DPS
    assert not (log.read_table_states().status[-1] & AxisStatus.ENABLED).any()     # servos off
    assert transitions(log.events)[-2:] == ["aborting", "failed"]
    assert any(e.kind == "info" and "servos off" in e.message for e in log.events)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_while_solving_ends_bench_run_with_exit_3_and_the_log_closed(config, tmp_path, monkeypatch,
                                                                                 signum):
    original_finish = BenchRun.finish

    def finish_interrupted(self):
        handler = signal.getsignal(signum)     # what the signal would run now (called here, not sent)
        assert callable(handler)
        handler(signum, None)
        return original_finish(self)

    monkeypatch.setattr(BenchRun, "finish", finish_interrupted)
    out = tmp_path / "out"
    stop = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
    before = [signal.getsignal(s) for s in stop]
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(out), "--quiet"])
    assert [signal.getsignal(s) for s in stop] == before      # the handlers put back as they were
    assert rc == 3, stderr
    log_path = only_file(out, "*.mcap")
    name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
    assert stderr.strip() == (f"bench run: interrupted ({name}) while solving; the table is at rest; no result "
                              f"written. Log: {log_path} (bench solve {log_path} solves it)")
    assert read_log(log_path).summary_present


def test_sigterm_aborts_bench_check_table_like_ctrl_c(tmp_path):
    config_path = tmp_path / "bench.toml"
    config_path.write_text(config_text(), encoding="utf-8")
    out = tmp_path / "out"
    proc = start_cli("check-table", "--config", str(config_path), "--dwell-s", "20", "--out", str(out), "--quiet")
    try:
        log_path = wait_for(lambda: next((p for p in out.glob("*.mcap") if p.stat().st_size > 100_000), None),
                            60.0, "the log to pass 100 kB", proc=proc)
        proc.send_signal(signal.SIGTERM)
        _, stderr = proc.communicate(timeout=60)
    finally:
        stop_process(proc)
    assert proc.returncode == 3, stderr
    assert len(stderr.strip().splitlines()) == 1 and "interrupted (SIGTERM)" in stderr, stderr
    log = read_log(log_path)
    assert log.summary_present and log.scan().complete, log.scan().damage
    assert np.abs(log.read_table_states().rates_dps[-1]).max() < AT_REST_DPS
    assert not (log.read_table_states().status[-1] & AxisStatus.ENABLED).any()
    assert transitions(log.events)[-2:] == ["aborting", "failed"]


ANSI_ESCAPE = re.compile(r"\x1b(\[[0-?]*[ -/]*[@-~]|[@-Z\\-_])")


class PtyOutput:
    """Everything a process writes to the pty, read by a thread until the pty closes."""

    def __init__(self, master: int):
        self.master, self.chunks = master, []
        self.thread = threading.Thread(target=self._read, daemon=True)
        self.thread.start()

    def _read(self) -> None:
        while True:
            try:
                data = os.read(self.master, 65536)
            except OSError:              # EIO: every writer has closed the pty
                return
            if not data:
                return
            self.chunks.append(data)

    def text(self) -> str:
        return b"".join(self.chunks).decode("utf-8", "replace")

    def plain(self) -> str:
        """The text without terminal escape sequences (styles split words into pieces)."""
        return ANSI_ESCAPE.sub("", self.text())


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP])
def test_a_stop_signal_ends_bench_tui_mid_run_with_the_table_stopped(signum, tmp_path):
    config_path = tmp_path / "bench.toml"
    # long dwells: the run must still be going when the signal comes
    config_path.write_text(config_text(dwell_s=120.0), encoding="utf-8")
    out = tmp_path / "out"
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 30, 100, 0, 0))
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "tui", "--config", str(config_path), "--out", str(out)],
                            cwd=REPO, stdin=slave, stdout=slave, stderr=slave,
                            env={**os.environ, "TERM": "xterm-256color", "COLUMNS": "100", "LINES": "30"})
    os.close(slave)
    output = PtyOutput(master)
    try:
        # "link: connected", not "connected": the first frame says "link: disconnected", and an "s" sent
        # before the auto-connect has finished is refused ("not connected (press c)")
        wait_for(lambda: "link: connected" in output.plain(), 60.0, "the TUI to connect", proc=proc)
        os.write(master, b"s")
        wait_for(lambda: "Start the calibration plan?" in output.text(), 20.0, "the start dialog", proc=proc)
        os.write(master, b"y")
        log_path = wait_for(lambda: next((p for p in out.glob("*.mcap") if p.stat().st_size > 200_000), None),
                            60.0, "the log to pass 200 kB", proc=proc)
        proc.send_signal(signum)
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)
        output.thread.join(timeout=10)
        os.close(master)
    name = signal.Signals(signum).name
    assert proc.returncode == 3, output.text()[-2000:]
    assert f"bench tui: interrupted ({name}); any run aborted, the table stopped" in output.text()
    log = read_log(log_path)
    assert log.summary_present and log.scan().complete, log.scan().damage
    assert transitions(log.events)[-2:] == ["aborting", "failed"]
    assert any(e.kind == "info" and "servos off" in e.message for e in log.events)
    assert np.abs(log.read_table_states().rates_dps[-1]).max() < AT_REST_DPS
    assert not (log.read_table_states().status[-1] & AxisStatus.ENABLED).any()


# -- 3. an output folder that cannot be written ------------------------------------------------------

@pytest.mark.parametrize("command", ["run", "check-table"])
def test_an_unwritable_output_folder_is_exit_2_one_line_and_no_device_opened(command, config, tmp_path, monkeypatch):
    (tmp_path / "afile").write_text("a file, not a folder\n", encoding="utf-8")
    out = tmp_path / "afile" / "sub"          # cannot be made, also for root (chmod would not stop root)
    opened = []
    original_open_turntable = devices_module.open_turntable
    monkeypatch.setattr(devices_module, "open_turntable",
                        lambda *args, **kwargs: opened.append(args) or original_open_turntable(*args, **kwargs))
    rc, _, stderr = cli([command, "--config", str(config), "--out", str(out), "--quiet"])
    assert rc == 2, stderr
    assert opened == []                       # the table was not even connected
    assert stderr.strip() == (f"bench {command}: cannot start: output folder {out}: {out.parent} is a file, "
                              "not a folder; nothing moved")
