"""The bulk decoder: many recorded frames at once, vectorised with numpy.

Gives exactly the samples and counts of `SampleAssembler` fed the same frames one by
one and then flushed (the rules are in `drivers.imu.assembler`); the tests hold the two
to that. Every step is a whole-array operation: id lookup, length check, CRC by a
256-entry table applied column by column, counter extraction, unwrapping by a cumulative
sum of wrapped differences, the reorder window by a running maximum, and grouping by
counter with a dense (counter, message) table.
"""

from __future__ import annotations

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.crc import crc8_columns, crc8_raw, id_bytes
from drivers.imu.layout import ImuLayout, SignalLayout, default_layout
from drivers.imu.samples import ImuSampleBlock, ImuStats


def _window_view(data: np.ndarray, sig: SignalLayout) -> tuple[np.ndarray, int]:
    """A zero-copy uint64 view of the 8 bytes holding `sig` in every row, and the shift to its LSB."""
    width = data.shape[1]
    o = min(sig.first_byte, width - 8)
    view = np.ndarray((data.shape[0],), dtype=">u8" if sig.big_endian else "<u8", buffer=data, offset=o,
                      strides=(width,))
    if sig.big_endian:
        return view, 8 * (7 - (sig.last_byte - o)) + sig.window_shift
    return view, sig.shift - 8 * o


def extract(data: np.ndarray, rows: np.ndarray, sig: SignalLayout) -> np.ndarray:
    """Raw int64 values of `sig` in `data[rows]` (data: C-contiguous uint8, width >= 8)."""
    view, shift = _window_view(data, sig)
    x = (view[rows].astype(np.uint64) >> np.uint64(shift)) & np.uint64(sig.mask)
    if sig.signed:
        up = np.uint64(64 - sig.length)
        return (x << up).view(np.int64) >> up.astype(np.int64)
    return x.view(np.int64)


def _as_arrays(ids, data, lengths, timestamps):
    try:
        ids = np.asarray(ids)
        data = np.asarray(data)
        if ids.ndim != 1 or (len(ids) and not np.issubdtype(ids.dtype, np.integer)):
            raise ImuFrameError(f"ids must be a 1-D integer array, got shape {ids.shape} {ids.dtype}")
        if data.ndim != 2 or data.dtype != np.uint8:
            raise ImuFrameError(f"data must be a 2-D uint8 array (frames x bytes), got {data.shape} {data.dtype}")
        n, width = data.shape
        if len(ids) != n:
            raise ImuFrameError(f"{len(ids)} ids for {n} frames of data")
        lengths = np.full(n, width, np.int64) if lengths is None else np.asarray(lengths)
        if lengths.shape != (n,) or (n and not np.issubdtype(lengths.dtype, np.integer)):
            raise ImuFrameError(f"lengths must be {n} integers, got {lengths.shape} {lengths.dtype}")
        if n and (lengths.min() < 0 or lengths.max() > width):
            raise ImuFrameError(f"frame lengths must lie in 0..{width} (the data width)")
        timestamps = np.zeros(n) if timestamps is None else np.asarray(timestamps, dtype=np.float64)
        if timestamps.shape != (n,):
            raise ImuFrameError(f"timestamps must be {n} numbers, got shape {timestamps.shape}")
    except (TypeError, ValueError) as exc:
        raise ImuFrameError(f"frames are not arrays of the expected kind: {exc}") from exc
    ids = ids.astype(np.int64)
    lengths = lengths.astype(np.int64)
    if width < 8 or not data.flags.c_contiguous:
        padded = np.zeros((n, max(width, 8)), np.uint8)
        padded[:, :width] = data
        data = padded
    return ids, data, lengths, timestamps


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
    ids, data, lengths, timestamps = _as_arrays(ids, data, lengths, timestamps)
    n, n_msgs = len(ids), len(layout.messages)
    stats = ImuStats(frames=n)

    msg_index = np.full(n, -1, np.int64)
    for k, m in enumerate(layout.messages):
        msg_index[ids == m.key] = k
    known = msg_index >= 0
    stats.unknown_id = int(n - known.sum())
    expected = np.array([m.length for m in layout.messages], np.int64)
    length_ok = known & (lengths == expected[np.maximum(msg_index, 0)])
    stats.wrong_length = int(known.sum() - length_ok.sum())

    valid = np.zeros(n, bool)
    counter_raw = np.zeros(n, np.int64)
    for k, m in enumerate(layout.messages):
        rows = np.flatnonzero(length_ok & (msg_index == k))
        if m.crc_byte is not None and len(rows):
            keep = [j for j in range(m.length) if j != m.crc_byte]
            start = crc8_raw(id_bytes(m.frame_id, m.is_extended_id))
            crc = crc8_columns(start, data[rows][:, keep])
            good = crc == data[rows, m.crc_byte]
            stats.crc_errors += int(len(rows) - good.sum())
            rows = rows[good]
        valid[rows] = True
        counter_raw[rows] = extract(data, rows, m.counter)

    vi = np.flatnonzero(valid)
    if len(vi) == 0:
        return ImuSampleBlock.empty(rate_hz), stats
    modulus = 1 << layout.counter_bits
    c = counter_raw[vi]
    d = np.diff(c) & (modulus - 1)
    d[d >= modulus >> 1] -= modulus
    u = np.empty(len(c), np.int64)
    u[0] = c[0]
    np.cumsum(d, out=u[1:])
    u[1:] += c[0]
    head = np.maximum.accumulate(u)
    accepted = (u > head - reorder_window) & (u >= u[0])
    stats.late = int(len(u) - accepted.sum())

    frames, ua, ka, ha = vi[accepted], u[accepted], msg_index[vi[accepted]], head[accepted]
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
    stats.incomplete_samples = int(((present > 0) & ~complete).sum())
    stats.counter_gaps = int(span - (present > 0).sum())

    raw = np.zeros((len(counters), 8), np.int64)
    for k, m in enumerate(layout.messages):
        sel = ka == k
        rows_k, frames_k = row[sel], frames[sel]
        for column, sig in m.values:
            raw[rows_k, column] = extract(data, frames_k, sig)
    last_frame = np.full(len(counters), -1, np.int64)
    np.maximum.at(last_frame, row, frames)
    block = ImuSampleBlock.from_raw(layout, counters[complete], timestamps[last_frame[complete]], raw[complete],
                                    rate_hz)
    return block, stats


def frames_from_messages(messages, width: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ids, data, lengths, timestamps) arrays for `decode_frames` from python-can `Message`s.

    `width` is the data array's width: 64 holds any CAN FD frame, 8 suffices for classic.
    """
    from drivers.imu.layout import EXTENDED_ID_FLAG

    messages = list(messages)
    n = len(messages)
    ids = np.fromiter((m.arbitration_id | (EXTENDED_ID_FLAG if m.is_extended_id else 0) for m in messages),
                      np.int64, n)
    lengths = np.fromiter((len(m.data) for m in messages), np.int64, n)
    if n and lengths.max() > width:
        raise ImuFrameError(f"a frame of {lengths.max()} bytes does not fit a data width of {width}")
    timestamps = np.fromiter((m.timestamp for m in messages), np.float64, n)
    buf = bytearray(n * width)
    for i, m in enumerate(messages):
        buf[i * width:i * width + len(m.data)] = m.data
    return ids, np.frombuffer(buf, np.uint8).reshape(n, width), lengths, timestamps
