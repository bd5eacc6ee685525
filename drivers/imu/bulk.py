"""The bulk decoder: many recorded frames at once, vectorised with numpy.

Gives exactly the samples and counts of `StreamDecoder` fed the same frames in pieces of
any size and then finished (the rules, and the array functions both apply, are in
`drivers.imu.rules`); the tests hold the two to that. Every step is a whole-array
operation: id lookup (one gather through a table of ids), length check and CRC (affine in
the data bits: 4 lookups of 16-bit chunks for a frame of up to 8 bytes, else a 256-entry
table applied column by column), screened in cache-sized blocks; counter extraction (a
typed view when the counter is whole bytes), unwrapping by wrapped differences, then the
grouping:
- in order (the usual recording: counters never decrease, no message repeats within a
  counter): a sample's frames are consecutive, so samples are read straight out of the
  frame array (strided views when nothing was lost);
- otherwise the reorder window by a running maximum and grouping by counter with a
  dense (counter, message) table.
"""

from __future__ import annotations

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.layout import ImuLayout, default_layout
from drivers.imu.numbering import FrameNumberer
from drivers.imu.rules import FrameScreen, SampleColumns, as_arrays, extract, unwrap_steps
from drivers.imu.samples import ImuSampleBlock, ImuStats


def decode_frames(ids, data, lengths=None, timestamps=None, layout: ImuLayout | None = None,
                  rate_hz: float = 1000.0, reorder_window: int = 8) -> tuple[ImuSampleBlock, ImuStats]:
    """Decode recorded frames (in arrival order) into samples and counts.

    `ids`: (n,) arbitration ids (`EXTENDED_ID_FLAG` set for 29-bit ids); `data`: (n, w)
    uint8, frame i's bytes in `data[i, :lengths[i]]`; `lengths`: (n,) data lengths
    (default w); `timestamps`: (n,) receive times (default 0). Malformed arrays raise
    `ImuFrameError`; malformed frames are counted, never raised.
    """
    layout = layout if layout is not None else default_layout()
    if not (isinstance(reorder_window, int) and reorder_window >= 1):
        raise ImuFrameError(f"reorder_window must be a positive integer, got {reorder_window!r}")
    ids, data, lengths, timestamps = as_arrays(ids, data, lengths, timestamps)
    if layout.time_stamp is None:
        return _decode(ids, data, lengths, timestamps, layout, rate_hz, reorder_window)
    # a time-stamped layout (sbg-ecan): frames numbered first (drivers.imu.numbering)
    numberer = FrameNumberer(layout, rate_hz)
    ids, data, lengths, timestamps = numberer.arrays(ids, data, lengths, timestamps)
    block, stats = _decode(ids, data, lengths, timestamps, numberer.numbered_layout, rate_hz, reorder_window)
    stats.frames += numberer.before_start
    stats.late += numberer.before_start
    return block, stats


def _decode(ids, data, lengths, timestamps, layout: ImuLayout, rate_hz: float,
            reorder_window: int) -> tuple[ImuSampleBlock, ImuStats]:
    n = len(ids)
    stats = ImuStats(frames=n)

    screen = FrameScreen(layout)
    msg_index, valid, n_known, n_length_ok = screen.screen(ids, data, lengths)
    stats.unknown_id = n - n_known
    stats.wrong_length = n_known - n_length_ok
    n_valid = int(np.count_nonzero(valid))
    stats.crc_errors = n_length_ok - n_valid
    if n_valid == 0:
        return ImuSampleBlock.empty(rate_hz), stats
    vi = None if n_valid == n else np.flatnonzero(valid)
    c = screen.counters(data, msg_index, valid, vi)
    d = unwrap_steps(c, layout.counter_bits)
    c0 = int(c[0])
    ka = msg_index if vi is None else msg_index[vi]
    if not len(d) or int(d.min()) >= 0:
        fast = _group_in_order(layout, data, timestamps, vi, ka, d, c0, rate_hz, stats)
        if fast is not None:
            return fast, stats
    u = np.full(n_valid, c0, np.int64)   # the unwrapped counters
    u[1:] += np.cumsum(d, dtype=np.int64)
    return _group_general(layout, data, timestamps, vi, ka, u, reorder_window, rate_hz, stats), stats


def _group_in_order(layout, data, timestamps, vi, ka, d, c0, rate_hz, stats) -> ImuSampleBlock | None:
    """The common case, counters never decreasing and no frame repeated: a sample's frames are
    consecutive, in message order. None when that does not hold (the general grouping applies)."""
    n_msgs = len(layout.messages)
    m = len(ka)
    new_row = d > 0
    if m > 1 and not (new_row | (np.diff(ka) > 0)).all():
        return None   # a message repeated within one counter: duplicates
    steps = np.flatnonzero(new_row)           # frame steps + 1 begins a new counter
    starts = np.zeros(len(steps) + 1, np.int64)
    starts[1:] = steps + 1
    rows = np.zeros(len(starts), np.int64)    # each counter minus the first one
    np.cumsum(d[steps], dtype=np.int64, out=rows[1:])
    counts = np.diff(starts, append=m)
    span = int(rows[-1]) + 1
    complete = counts == n_msgs
    first = starts[complete]   # each complete sample holds message 0, 1, ... in this order
    stats.frames_ok = m
    stats.samples = len(first)
    stats.joined_mid_sample = int(not complete[0])      # the first counter's sample began before the stream
    stats.left_mid_sample = int(len(starts) > 1 and not complete[-1])   # the last one ended after it
    stats.incomplete_samples = len(starts) - len(first) - stats.joined_mid_sample - stats.left_mid_sample
    stats.counter_gaps = span - len(starts)
    if len(first) == 0:
        return ImuSampleBlock.empty(rate_hz)
    counters = rows[complete]
    counters += c0
    if vi is None and len(first) * n_msgs == m:   # every frame used, in order: strided views, no gathers
        last = timestamps[n_msgs - 1::n_msgs]
        return SampleColumns(layout).block(data, None, counters, np.array(last, dtype=np.float64), rate_hz)

    def frames_of(k):
        return first + k if vi is None else vi[first + k]
    last = timestamps[frames_of(n_msgs - 1)]
    return SampleColumns(layout).block(data, frames_of, counters, np.array(last, dtype=np.float64), rate_hz)


def _group_general(layout, data, timestamps, vi, ka, u, reorder_window, rate_hz, stats) -> ImuSampleBlock:
    """Reordering window, duplicates and grouping by counter for any arrival order."""
    n_msgs = len(layout.messages)
    ka = ka.astype(np.int64)
    vi = np.arange(len(u)) if vi is None else vi
    head = np.maximum.accumulate(u)
    accepted = (u > head - reorder_window) & (u >= u[0])
    stats.late = int(len(u) - accepted.sum())

    frames, ua, ka, ha = vi[accepted], u[accepted], ka[accepted], head[accepted]
    u0, u_last = int(u[0]), int(head[-1])
    span = u_last - u0 + 1
    if span <= 4 * len(ua) + 1024:
        counters = np.arange(u0, u_last + 1, dtype=np.int64)
        row = ua - u0
    else:   # a huge counter jump: group by the counters that occur instead of the whole range
        counters, row = np.unique(ua, return_inverse=True)
        row = row.reshape(-1)
    key = row * n_msgs + ka
    first = np.ones(len(key), bool)
    multi = np.bincount(key, minlength=len(counters) * n_msgs)[key] > 1
    if multi.any():
        idx = np.flatnonzero(multi)
        order = idx[np.argsort(key[idx], kind="stable")]
        sorted_keys = key[order]
        first[order[1:][sorted_keys[1:] == sorted_keys[:-1]]] = False
    stats.duplicates = int(len(key) - first.sum())
    frames, row, ka, ua, ha = frames[first], row[first], ka[first], ua[first], ha[first]
    stats.frames_ok = len(frames)
    stats.out_of_order = int((ua < ha).sum())

    present = np.bincount(row, minlength=len(counters))
    complete = present == n_msgs
    stats.samples = int(complete.sum())
    # counters[0] is the first valid frame's: its sample, incomplete, began before the stream was joined
    stats.joined_mid_sample = int(present[0] > 0 and not complete[0])
    # the newest counter's sample, incomplete, was still being sent when the stream ended
    stats.left_mid_sample = int(len(counters) > 1 and present[-1] > 0 and not complete[-1])
    stats.incomplete_samples = (int(((present > 0) & ~complete).sum()) - stats.joined_mid_sample
                                - stats.left_mid_sample)
    stats.counter_gaps = int(span - (present > 0).sum())

    raw = np.zeros((len(counters), 8), np.int64)
    for k, m in enumerate(layout.messages):
        sel = ka == k
        rows_k, frames_k = row[sel], frames[sel]
        for column, sig in m.values:
            raw[rows_k, column] = extract(data, frames_k, sig)
    last_frame = np.full(len(counters), -1, np.int64)
    np.maximum.at(last_frame, row, frames)
    return ImuSampleBlock.from_raw(layout, counters[complete], timestamps[last_frame[complete]], raw[complete],
                                   rate_hz)


__all__ = ["decode_frames"]
