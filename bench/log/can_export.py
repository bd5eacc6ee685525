"""The raw CAN frames of a run log as python-can Messages, and written in the formats CAN tools read.

`export_can(log, path)` writes `/can/raw` with python-can's own writers, chosen by the file's
extension: `.asc` (Vector ASCII), `.blf` (Vector binary logging format), `.log` (candump -L) or
`.csv`. Timestamps are the frames' recorded ones (the run clock); a time range is given in
seconds from the log's first frame. Frames are read chunk by chunk and written in batches, so
memory stays bounded whatever the log's size.
"""

from __future__ import annotations

from pathlib import Path

import can

from bench.errors import BenchError
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
    """An export that cannot be done (unknown format, empty range); one line."""


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
    writer_class, _ = CAN_FORMATS[can_format(path)]
    lo, hi = frame_range(log, from_s, to_s)
    if hi <= lo:
        raise CanExportError(f"{log.path}: no CAN frames"
                             + ("" if from_s is None and to_s is None else " in the time range given"))
    left_out = 0
    with writer_class(str(path)) as writer:
        first = 0   # index of the piece's first frame in the log
        for piece in log.can_pieces():
            n = len(piece[1])
            a, b = max(lo, first) - first, min(hi, first + n) - first
            for start in range(a, b, _BATCH):
                for message in can_messages(piece, start, min(b, start + _BATCH)):
                    if frame_time_ok(message.timestamp):
                        writer.on_message_received(message)
                    else:
                        left_out += 1
            first += n
            if first >= hi:
                break
    return hi - lo - left_out, left_out


def frame_time_ok(time_s: float) -> bool:
    """Whether a frame's recorded time is one a writer can date: finite, 0..`MAX_FRAME_TIME_S` (a log is
    hostile: NaN or 1e300 made the ASC and BLF writers raise halfway through the file)."""
    return 0.0 <= time_s <= MAX_FRAME_TIME_S


__all__ = ["CAN_FORMATS", "MAX_FRAME_TIME_S", "CanExportError", "can_format", "can_messages", "export_can",
           "frame_range", "frame_time_ok"]
