"""`bench export-can`: a log's raw CAN frames read back by python-can's own readers (issue 14, item 5)."""

from __future__ import annotations

import can
import numpy as np
import pytest

from bench.log.reader import read_log
from tests.helpers.run import cli


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
    assert back[0].timestamp == pytest.approx(stamps_s[inside][0], abs=1e-6)


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
