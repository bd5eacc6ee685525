"""Fail safe: every way a command that moves the table can end leaves the table stopped (issue 13).

A listener that fails (the recorder on a full disk, the progress output on a closed
pipe), SIGTERM and SIGHUP like Ctrl-C, an output folder that cannot be written.
Runs are the short simulated plan of tests/helpers/run.py, in-process or as
subprocesses (for signals and pipes); every wait is bounded.
"""

from __future__ import annotations

import errno
import io
import os

import numpy as np
import pytest

import bench.log.recorder as recorder_module
from bench.config.load import load_config
from bench.log.reader import read_log
from bench.plan.events import RunListener
from bench.run.runner import BenchRun, compile_from_config
from tests.helpers.run import (
    AT_REST_DPS,
    Trigger,
    cli,
    config_text,
    only_file,
    start_cli,
    step_index,
    stop_process,
    transitions,
)


class FillingDisk(io.RawIOBase):
    """A file on a disk that fills up when told: once `FillingDisk.full` is set, every write fails with ENOSPC."""

    full = False

    def __init__(self, path: str):
        super().__init__()
        self._file = io.FileIO(path, "wb")

    @classmethod
    def open(cls, path, mode: str = "r", *args, **kwargs):
        assert mode == "wb", mode
        return io.BufferedWriter(cls(path))

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def write(self, data) -> int:
        if FillingDisk.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._file.write(data)

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._file.seek(pos, whence)

    def tell(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        self._file.close()
        super().close()


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
    assert log.summary_present and log.complete, log.damage
    faults = [e for e in log.events if e.kind == "fault"]
    assert len(faults) == 1 and "ProgressPrinter failed: BrokenPipeError" in faults[0].message
    assert transitions(log.events)[-2:] == ["aborting", "failed"]
    assert any(e.kind == "info" and "servos off" in e.message for e in log.events)
    assert np.abs(log.table_states.rates_dps[-1]).max() < AT_REST_DPS
    assert not list(out.glob("*.result.json"))

