"""The raw CAN frames of a run log as python-can Messages, and written in the formats CAN tools read.

`export_can(log, path)` writes `/can/raw` with python-can's own writers, chosen by the file's
extension: `.asc` (Vector ASCII), `.blf` (Vector binary logging format), `.log` (candump -L) or
`.csv`. Timestamps are wall-clock (Unix) times: the frames' recorded run-clock times moved so that
the run's start (its first transition, "run started"; the first frame in a log without one) falls
on the log's `run.started_utc` (whole seconds, taken as the log was opened). The BLF header's start
and the ASC header's `date` are then the first written frame's date (local time in the ASC, as CANoe
and python-can write it); a log without a readable `run.started_utc` keeps the run clock (a 1970
date) and `export_can` says so. python-can's CSV has no CAN FD flag: CAN FD frames are refused for
`.csv` (the other formats keep the flag). A time range is given in seconds from the log's first
frame. Frames are read chunk by chunk and written in batches, so memory stays bounded whatever the
log's size.
"""

from __future__ import annotations

import calendar
import time
from datetime import datetime
from pathlib import Path
from typing import Any

import can

from bench.errors import BenchError
from bench.log.events import Transition
from bench.log.format import EXTENDED_ID_FLAG, FLAG_BRS, FLAG_ERROR, FLAG_ESI, FLAG_FD, FLAG_REMOTE
from bench.log.reader import RunLog

#: extension -> (python-can writer, what it is)
CAN_FORMATS: dict[str, tuple[type[can.io.generic.MessageWriter], str]] = {
    ".asc": (can.ASCWriter, "Vector ASC"),
    ".blf": (can.BLFWriter, "Vector BLF"),
    ".log": (can.CanutilsLogWriter, "candump -L log"),
    ".csv": (can.CSVWriter, "python-can CSV"),
}
_BATCH = 10_000
#: the latest frame time exported, s (the run clock, or the epoch: 1e10 s is the year 2286)
MAX_FRAME_TIME_S = 1e10


class CanExportError(BenchError):
    """An export that cannot be done (unknown format, empty range, CAN FD frames for CSV); one line."""


class _DatedAscWriter(can.ASCWriter):
    """python-can's ASC writer with the header's `date` set to the first frame's time (python-can writes the
    time of the export there, and every frame's time relative to the first frame: a reader adds them)."""

    def __init__(self, file: str, first_frame_s: float):
        super().__init__(file)
        when = datetime.fromtimestamp(first_frame_s)
        date = when.strftime(self.FORMAT_DATE.format(f"{when.microsecond // 1000:03d}"))
        self.file.seek(0)
        self.file.truncate()
        self.file.write(f"date {date}\nbase hex  timestamps absolute\ninternal events logged\n")


def started_unix_s(log: RunLog) -> float | None:
    """The log's `run.started_utc` as Unix time, None when it records none (or not as "YYYY-MM-DDTHH:MM:SSZ")."""
    run = log.metadata.get("run", {})
    text = run.get("started_utc") if isinstance(run, dict) else None
    try:
        return float(calendar.timegm(time.strptime(str(text), "%Y-%m-%dT%H:%M:%SZ")))
    except (ValueError, OverflowError):
        return None


def wall_clock_offset_s(log: RunLog) -> float | None:
    """Seconds to add to a run-clock time for Unix time: `run.started_utc` minus the run clock at the run's
    start (its first transition; the first frame without one). None when the log records no start."""
    started = started_unix_s(log)
    if started is None:
        return None
    start_s = next((e.time_s for e in log.events if isinstance(e, Transition)), None)
    if start_s is None:
        stamps = log.read_can_timestamps_s()
        start_s = float(stamps[0]) if len(stamps) else 0.0
    return started - start_s


def can_messages(frames, lo: int, hi: int) -> list[can.Message]:
    """Frames `lo:hi` of `frames` ((timestamps, ids, data, lengths, flags), as `RunLog.can_pieces` gives
    them) as python-can Messages, as the bus delivered them (channel not recorded)."""
    stamps_all, ids_all, data_all, lengths_all, flags_all = frames
    ids = ids_all[lo:hi].tolist()
    flags = flags_all[lo:hi].tolist()
    lengths = lengths_all[lo:hi].tolist()
    stamps = stamps_all[lo:hi].tolist()
    data = data_all[lo:hi]
    out = []
    for j, (i, f, n, t) in enumerate(zip(ids, flags, lengths, stamps)):
        out.append(can.Message(timestamp=t, arbitration_id=i & ~EXTENDED_ID_FLAG,
                               is_extended_id=bool(i & EXTENDED_ID_FLAG),
                               is_remote_frame=bool(f & FLAG_REMOTE), is_error_frame=bool(f & FLAG_ERROR),
                               dlc=n, data=data[j, :n].tobytes(), is_fd=bool(f & FLAG_FD),
                               bitrate_switch=bool(f & FLAG_BRS), error_state_indicator=bool(f & FLAG_ESI)))
    return out


def can_format(path: str | Path) -> str:
    """The extension of `path` if it is a format `export_can` writes; CanExportError otherwise."""
    suffix = Path(path).suffix.lower()
    if suffix not in CAN_FORMATS:
        known = ", ".join(f"{ext} ({what})" for ext, (_, what) in CAN_FORMATS.items())
        raise CanExportError(f"{path}: unknown CAN log format {suffix or '(no extension)'!r}; known: {known}")
    return suffix


def frame_range(log: RunLog, from_s: float | None = None, to_s: float | None = None) -> tuple[int, int]:
    """Indices lo:hi of the frames from `from_s` to `to_s` seconds after the log's first frame (inclusive)."""
    stamps = log.read_can_timestamps_s()
    if not len(stamps):
        return 0, 0
    t0 = float(stamps[0])
    lo = 0 if from_s is None else int(stamps.searchsorted(t0 + from_s, side="left"))
    hi = len(stamps) if to_s is None else int(stamps.searchsorted(t0 + to_s, side="right"))
    return lo, max(lo, hi)


def export_can(log: RunLog, path: str | Path, from_s: float | None = None,
               to_s: float | None = None) -> tuple[int, int]:
    """Write the log's frames (optionally from `from_s` to `to_s` s after the first frame) to `path` in the
    format its extension names; returns how many were written and how many were left out because their time
    is no time (`frame_time_ok`: the writers turn it into a date). CanExportError when there is nothing."""
    suffix = can_format(path)
    lo, hi = frame_range(log, from_s, to_s)
    if hi <= lo:
        raise CanExportError(f"{log.path}: no CAN frames"
                             + ("" if from_s is None and to_s is None else " in the time range given"))
    offset_s = wall_clock_offset_s(log) or 0.0
    stamps = log.read_can_timestamps_s()[lo:hi]
    dated = stamps[(stamps >= 0.0) & (stamps <= MAX_FRAME_TIME_S)]
    first_s = (float(dated[0]) if len(dated) else 0.0) + offset_s
    left_out = 0
    with _writer(suffix, path, first_s) as writer:
        first = 0   # index of the piece's first frame in the log
        for piece in log.can_pieces():
            n = len(piece[1])
            a, b = max(lo, first) - first, min(hi, first + n) - first
            for start in range(a, b, _BATCH):
                for message in can_messages(piece, start, min(b, start + _BATCH)):
                    if not frame_time_ok(message.timestamp):
                        left_out += 1
                        continue
                    if message.is_fd and suffix == ".csv":
                        raise CanExportError(f"{path}: python-can's CSV has no CAN FD flag and the log's frames "
                                             f"are CAN FD (the first at {message.timestamp:.6f} s on the run clock): "
                                             "write .asc, .blf or .log, which keep it")
                    message.timestamp += offset_s
                    writer.on_message_received(message)
            first += n
            if first >= hi:
                break
    return hi - lo - left_out, left_out


def _writer(suffix: str, path: str | Path, first_frame_s: float) -> Any:
    if suffix == ".asc":
        return _DatedAscWriter(str(path), first_frame_s)
    return CAN_FORMATS[suffix][0](str(path))


def frame_time_ok(time_s: float) -> bool:
    """Whether a frame's recorded time is one a writer can date: finite, 0..`MAX_FRAME_TIME_S` (a log is
    hostile: NaN or 1e300 made the ASC and BLF writers raise halfway through the file)."""
    return 0.0 <= time_s <= MAX_FRAME_TIME_S


__all__ = ["CAN_FORMATS", "MAX_FRAME_TIME_S", "CanExportError", "can_format", "can_messages", "export_can",
           "frame_range", "frame_time_ok", "started_unix_s", "wall_clock_offset_s"]
