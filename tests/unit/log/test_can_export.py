"""`bench export-can`: a log's raw CAN frames read back by python-can's own readers (issue 14, item 5); the
files dated by the run's wall-clock start, CAN FD refused for CSV (issue 33, item 2)."""

from __future__ import annotations

import calendar
import time

import can
import numpy as np
import pytest

from bench.log.can_export import wall_clock_offset_s
from bench.log.events import make_event
from bench.log.reader import read_log
from bench.log.recorder import McapRecorder
from tests.helpers.run import cli

#: the small log's run: started at this UTC time, when its run clock read RUN_START_S
STARTED_UTC, RUN_START_S = "2026-11-27T14:30:05Z", 1234.5
STARTED_UNIX_S = calendar.timegm(time.strptime(STARTED_UTC, "%Y-%m-%dT%H:%M:%SZ"))


def _small_log(path, fd: bool = False, started_utc: str | None = STARTED_UTC):
    """A log of 50 frames 10 ms apart from 0.25 s after the run's start (on a hardware-like run clock), one of
    them CAN FD when `fd`; returns the frames' run-clock times."""
    run = {"run_id": "r-1", "mode": "hardware"} | ({"started_utc": started_utc} if started_utc else {})
    recorder = McapRecorder(path, metadata={"run": run}, clock=lambda: RUN_START_S)
    recorder.on_event(make_event(RUN_START_S, "transition", "run started", state="running", data={"from": "idle"}))
    times = RUN_START_S + 0.25 + 0.01 * np.arange(50)
    messages = [can.Message(timestamp=float(t), arbitration_id=0x100 + k % 3, is_extended_id=False,
                            data=bytes([k % 256] * 8)) for k, t in enumerate(times)]
    if fd:
        messages[20] = can.Message(timestamp=float(times[20]), arbitration_id=0x123, is_extended_id=False,
                                   is_fd=True, bitrate_switch=True, data=bytes(range(32)))
    recorder.on_can_frames(messages)
    recorder.close()
    return times


@pytest.fixture(scope="module")
def log_path(short_run):
    return short_run.log


@pytest.mark.slow
@pytest.mark.parametrize("extension", [".asc", ".blf", ".log", ".csv"])
def test_every_format_reads_back_frame_for_frame(log_path, tmp_path, extension):
    log = read_log(log_path)
    out = tmp_path / f"frames{extension}"
    rc, stdout, stderr = cli(["export-can", str(log_path), "--out", str(out)])
    assert rc == 0, stderr
    frames = log.read_can_frames()
    n = len(frames.ids)
    assert stdout.strip() == f"wrote {n} CAN frames to {out}"
    back = list(can.LogReader(str(out)))
    assert len(back) == n
    ids = np.array([m.arbitration_id | (1 << 31 if m.is_extended_id else 0) for m in back], dtype=np.uint32)
    assert (ids == frames.ids).all()
    assert [bytes(m.data) for m in back] == [frames.data[k, :frames.lengths[k]].tobytes() for k in range(n)]
    stamps = np.array([m.timestamp for m in back])
    # relative times survive every format to its resolution (ASC and BLF: 10 us or better)
    assert np.abs((stamps - stamps[0]) - (frames.timestamp_s - frames.timestamp_s[0])).max() < 2e-5


def test_a_time_range_keeps_the_frames_inside_it(log_path, tmp_path):
    log = read_log(log_path)
    out = tmp_path / "part.log"
    rc, stdout, stderr = cli(["export-can", str(log_path), "--out", str(out), "--from-s", "10", "--to-s", "12.5"])
    assert rc == 0, stderr
    stamps_s = log.read_can_timestamps_s()
    rel = stamps_s - stamps_s[0]
    inside = (rel >= 10.0 - 1e-9) & (rel <= 12.5 + 1e-9)
    assert 0 < inside.sum() < len(rel)
    back = list(can.LogReader(str(out)))
    assert len(back) == inside.sum()
    assert back[0].timestamp == pytest.approx(stamps_s[inside][0] + wall_clock_offset_s(log), abs=1e-6)


@pytest.mark.parametrize("reader", [can.BLFReader, can.ASCReader, can.CanutilsLogReader, can.CSVReader])
def test_the_frames_are_dated_by_the_runs_wall_clock_start(tmp_path, reader):
    """Each frame reads back at started_utc + (its run-clock time - the run clock at the start): the BLF header's
    start and the ASC header's date are the first frame's date, not 1970 or the time of the export."""
    log_path = tmp_path / "small.mcap"
    times = _small_log(log_path)
    extension = {can.BLFReader: ".blf", can.ASCReader: ".asc", can.CanutilsLogReader: ".log", can.CSVReader: ".csv"}
    out = tmp_path / f"frames{extension[reader]}"
    rc, _, stderr = cli(["export-can", str(log_path), "--out", str(out)])
    assert rc == 0 and not stderr, stderr
    # python-can's ASC reader gives times from the header's date only when asked to
    opened = reader(str(out), relative_timestamp=False) if reader is can.ASCReader else reader(str(out))
    back = list(opened)
    expected = STARTED_UNIX_S + (times - RUN_START_S)
    assert len(back) == len(times)
    assert np.abs(np.array([m.timestamp for m in back]) - expected).max() < 2e-5
    if reader is can.BLFReader:
        assert opened.start_timestamp == pytest.approx(expected[0], abs=1e-3)
        assert time.gmtime(opened.start_timestamp)[:6] == (2026, 11, 27, 14, 30, 5)
    if reader is can.ASCReader:
        assert opened.start_time == pytest.approx(expected[0], abs=1e-3)


def test_a_log_without_its_start_keeps_the_run_clock_and_says_so(tmp_path):
    log_path = tmp_path / "small.mcap"
    times = _small_log(log_path, started_utc=None)
    out = tmp_path / "frames.log"
    rc, _, stderr = cli(["export-can", str(log_path), "--out", str(out)])
    assert rc == 0 and "no run.started_utc" in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert [m.timestamp for m in can.LogReader(str(out))] == pytest.approx(times.tolist(), abs=1e-6)


def test_csv_refuses_can_fd_frames_and_the_other_formats_keep_the_flag(tmp_path):
    log_path = tmp_path / "fd.mcap"
    _small_log(log_path, fd=True)
    out = tmp_path / "frames.csv"
    rc, _, stderr = cli(["export-can", str(log_path), "--out", str(out)])
    assert rc == 2 and "CAN FD" in stderr and ".blf" in stderr and len(stderr.strip().splitlines()) == 1, stderr
    assert not list(tmp_path.glob("*frames*"))      # nothing half-written left behind
    for extension in (".asc", ".blf", ".log"):
        out = tmp_path / f"frames{extension}"
        rc, _, stderr = cli(["export-can", str(log_path), "--out", str(out)])
        assert rc == 0, stderr
        fd = [m for m in can.LogReader(str(out)) if m.is_fd]
        assert len(fd) == 1 and fd[0].bitrate_switch and bytes(fd[0].data) == bytes(range(32)), extension


@pytest.mark.parametrize("args, fragment", [
    (["--out", "frames.mf4x"], "unknown CAN log format '.mf4x'; known: .asc (Vector ASC)"),
    (["--out", "frames.log", "--from-s", "1e9"], "no CAN frames in the time range given"),
])
def test_bad_requests_are_one_line_and_exit_2(log_path, tmp_path, args, fragment):
    args = [str(tmp_path / a) if a.startswith("frames") else a for a in args]
    rc, _, stderr = cli(["export-can", str(log_path), *args])
    assert rc == 2 and len(stderr.strip().splitlines()) == 1 and fragment in stderr, stderr
    assert not list(tmp_path.iterdir())


def test_a_file_that_is_not_a_log_is_one_line(tmp_path):
    bogus = tmp_path / "x.mcap"
    bogus.write_bytes(b"not an mcap file at all")
    rc, _, stderr = cli(["export-can", str(bogus), "--out", str(tmp_path / "f.asc")])
    assert rc == 2 and len(stderr.strip().splitlines()) == 1 and "not an MCAP file" in stderr, stderr
