"""The bulk decoder: many recorded frames at once, vectorised with numpy.

Gives exactly the samples and counts of `SampleAssembler` fed the same frames one by
one and then flushed (the rules are in `drivers.imu.assembler`); the tests hold the two
to that. Every step is a whole-array operation: id lookup (one gather through a table of
ids), length check and CRC (affine in the data bits: 4 lookups of 16-bit chunks for a
frame of up to 8 bytes, else a 256-entry table applied column by column), screened in
cache-sized blocks; counter extraction (a typed view when the counter is whole bytes),
unwrapping by wrapped differences, then the grouping:
- in order (the usual recording: counters never decrease, no message repeats within a
  counter): a sample's frames are consecutive, so samples are read straight out of the
  frame array (strided views when nothing was lost);
- otherwise the reorder window by a running maximum and grouping by counter with a
  dense (counter, message) table.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.crc import crc8_columns, crc8_raw, id_bytes, linear_crc
from drivers.imu.layout import EXTENDED_ID_FLAG, ImuLayout, SignalLayout, default_layout
from drivers.imu.numbering import FrameNumberer
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


def extract(data: np.ndarray, rows: np.ndarray | slice, sig: SignalLayout) -> np.ndarray:
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
    if not len(ids):   # an empty array of any dtype (even float) is fine
        ids = ids.astype(np.int64)
    if width < 8 or not data.flags.c_contiguous:
        padded = np.zeros((n, max(width, 8)), np.uint8)
        padded[:, :width] = data
        data = padded
    return ids, data, lengths, timestamps


#: Frames screened per step: the temporaries of a block stay in the CPU caches.
_BLOCK = 1 << 16
#: Screening runs on worker threads from this many blocks on.
_PARALLEL_BLOCKS = 8
_WORKERS = min(4, os.cpu_count() or 1)


def _screen(ids: np.ndarray, data: np.ndarray, lengths: np.ndarray, layout: ImuLayout):
    """Message index (-1: unknown id), validity (known id, right length, CRC good) and the counts.

    Returns (msg_index, valid, known frames, frames of the right length)."""
    msgs, keys, n = layout.messages, layout.keys, len(ids)
    dtype = np.int8 if len(keys) < 127 else np.int32
    top = max(keys)
    lut = None
    if n and top < (1 << 16) and (ids.dtype.kind == "u" or int(ids.min()) >= 0):
        lut = np.full(top + 2, -1, dtype)   # one gather through a table of every id up to the largest key
        for k, key in enumerate(keys):
            lut[key] = k
    expected = np.array([m.length for m in msgs], np.int64)
    one_length = int(expected[0]) if (expected == expected[0]).all() else None
    shapes = {(m.length, m.crc_byte) for m in msgs}
    length, crc_byte = next(iter(shapes))
    if len(shapes) == 1 and crc_byte is None:
        crc_mode = "none"
    elif len(shapes) == 1 and length <= 8:
        # every frame at once: the CRC is affine in the data bits, 4 lookups of 16 bits each
        crc_mode = "linear"
        lin = linear_crc(length, crc_byte)
        tables = [(first_bit // 16, table) for first_bit, table in lin.tables_np]
        id_const = np.array([lin.id_constant(m.frame_id, m.is_extended_id) for m in msgs] + [0], np.uint8)
    else:
        crc_mode = "per message"
    msg_index = np.empty(n, dtype)
    valid = np.empty(n, bool)

    def screen_block(a: int) -> tuple[int, int]:
        b = min(n, a + _BLOCK)
        if lut is not None:
            mi = lut[np.minimum(ids[a:b], top + 1)]
        else:
            mi = np.full(b - a, -1, dtype)
            for k, key in enumerate(keys):
                mi[ids[a:b] == key] = k
        msg_index[a:b] = mi
        known = mi >= 0
        if one_length is not None:
            ok = known & (lengths[a:b] == one_length)
        else:
            ok = known & (lengths[a:b] == expected[np.maximum(mi, 0)])
        counts = int(np.count_nonzero(known)), int(np.count_nonzero(ok))
        if crc_mode == "linear":
            chunks = data[a:b, :8].view("<u2")
            crc = id_const[mi]
            for column, table in tables:
                crc ^= table[chunks[:, column]]
            ok &= crc == data[a:b, crc_byte]
        valid[a:b] = ok
        return counts

    blocks = range(0, n, _BLOCK)
    if len(blocks) >= _PARALLEL_BLOCKS and _WORKERS > 1:
        # numpy releases the GIL in these block operations: the blocks screen on every core
        with ThreadPoolExecutor(_WORKERS, thread_name_prefix="imu-screen") as pool:
            counts = list(pool.map(screen_block, blocks))
    else:
        counts = [screen_block(a) for a in blocks]
    n_known = sum(k for k, _ in counts)
    n_length_ok = sum(k for _, k in counts)
    if crc_mode == "per message":
        valid = _check_crcs(data, msg_index, valid, layout)
    return msg_index, valid, n_known, n_length_ok


def _same_signal(sigs) -> bool:
    """True when the signals sit in the same bits of their frames (names aside)."""
    first = sigs[0]
    return all((s.length, s.signed, s.big_endian, s.shift, s.first_byte, s.last_byte, s.window_shift)
               == (first.length, first.signed, first.big_endian, first.shift, first.first_byte, first.last_byte,
                   first.window_shift) for s in sigs)


def _extract_all(data: np.ndarray, sig: SignalLayout) -> np.ndarray:
    """Raw values of `sig` in every row; a zero-copy view when it is a whole byte-aligned integer."""
    nbytes = sig.last_byte - sig.first_byte + 1
    if sig.length == 8 * nbytes and nbytes in (1, 2, 4, 8) and sig.window_shift == 0:
        kind = "i" if sig.signed else "u"
        dtype = np.dtype(f"{'>' if sig.big_endian else '<'}{kind}{nbytes}")
        return np.ndarray((data.shape[0],), dtype=dtype, buffer=data, offset=sig.first_byte,
                          strides=(data.shape[1],))
    return extract(data, slice(None), sig)


def _check_crcs(data: np.ndarray, msg_index: np.ndarray, length_ok: np.ndarray, layout: ImuLayout) -> np.ndarray:
    """The frames of the right length whose CRC checks out (or whose message has none), message by message."""
    valid = np.zeros(len(msg_index), bool)
    for k, m in enumerate(layout.messages):
        rows = np.flatnonzero(length_ok & (msg_index == k))
        if m.crc_byte is not None and len(rows):
            keep = [j for j in range(m.length) if j != m.crc_byte]
            start = crc8_raw(id_bytes(m.frame_id, m.is_extended_id))
            crc = crc8_columns(start, data[rows][:, keep])
            rows = rows[crc == data[rows, m.crc_byte]]
        valid[rows] = True
    return valid


def _counters(data: np.ndarray, msg_index: np.ndarray, valid: np.ndarray, vi, layout: ImuLayout) -> np.ndarray:
    """Raw counter values of the valid frames (`vi`, None when every frame is valid), in frame order."""
    msgs = layout.messages
    if _same_signal([m.counter for m in msgs]):
        c = _extract_all(data, msgs[0].counter)
        return c if vi is None else c[vi]
    counter_raw = np.zeros(len(msg_index), np.int64)
    for k, m in enumerate(msgs):
        rows = np.flatnonzero(valid & (msg_index == k))
        counter_raw[rows] = extract(data, rows, m.counter)
    return counter_raw if vi is None else counter_raw[vi]


def _unwrap_steps(c: np.ndarray, counter_bits: int) -> np.ndarray:
    """Differences of consecutive counters, wrapped into -modulus/2 .. modulus/2 - 1."""
    if c.dtype.kind == "u" and c.dtype.itemsize * 8 == counter_bits:
        # unsigned subtraction wraps by itself; read as signed it is the shortest step
        return np.diff(c).view(f"i{c.dtype.itemsize}")
    modulus = 1 << counter_bits
    # Bound to a name first: written inline, mypy typed np.diff(...) with numpy's datetime64 overload
    # (a timedelta64 result, which has no `&`); the values are int64 either way.
    c64 = c.astype(np.int64)
    d = np.diff(c64) & (modulus - 1)
    d[d >= modulus >> 1] -= modulus
    return d


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

    msg_index, valid, n_known, n_length_ok = _screen(ids, data, lengths, layout)
    stats.unknown_id = n - n_known
    stats.wrong_length = n_known - n_length_ok
    n_valid = int(np.count_nonzero(valid))
    stats.crc_errors = n_length_ok - n_valid
    if n_valid == 0:
        return ImuSampleBlock.empty(rate_hz), stats
    vi = None if n_valid == n else np.flatnonzero(valid)
    c = _counters(data, msg_index, valid, vi, layout)
    d = _unwrap_steps(c, layout.counter_bits)
    c0 = int(c[0])
    ka = msg_index if vi is None else msg_index[vi]
    if not len(d) or int(d.min()) >= 0:
        fast = _group_in_order(layout, data, timestamps, vi, ka, d, c0, rate_hz, stats)
        if fast is not None:
            return fast, stats
    u = np.full(n_valid, c0, np.int64)   # the unwrapped counters
    u[1:] += np.cumsum(d, dtype=np.int64)
    return _group_general(layout, data, timestamps, vi, ka, u, reorder_window, rate_hz, stats), stats


def _values(data: np.ndarray, rows, sig: SignalLayout) -> np.ndarray:
    """Raw values of `sig` in `data[rows]`: a view (typed, no shifts) for a whole byte-aligned integer,
    else as `extract` gives them."""
    nbytes = sig.last_byte - sig.first_byte + 1
    if sig.length == 8 * nbytes and nbytes in (1, 2, 4) and sig.window_shift == 0:
        dtype = np.dtype(f"{'>' if sig.big_endian else '<'}{'i' if sig.signed else 'u'}{nbytes}")
        view = np.ndarray((data.shape[0],), dtype=dtype, buffer=data, offset=sig.first_byte,
                          strides=(data.shape[1],))
        return view[rows]
    return extract(data, rows, sig)


def _block(layout: ImuLayout, data: np.ndarray, frames_of, counters: np.ndarray, receive_time_s: np.ndarray,
           rate_hz: float) -> ImuSampleBlock:
    """The samples straight from the frames, `frames_of(k)` indexing message k's frame of every sample:
    exactly `ImuSampleBlock.from_raw` of the raw values (raw * scale + offset in float64), without the
    (samples, 8) intermediate arrays."""
    samples = len(counters)
    where = {column: (k, sig) for k, m in enumerate(layout.messages) for column, sig in m.values}
    scale, offset = layout.scale, layout.offset

    def scaled(column: int, out: np.ndarray) -> None:
        if column in where:
            k, sig = where[column]
            np.multiply(_values(data, frames_of(k), sig), scale[column], out=out)
            out += offset[column]
        else:
            out[...] = np.float64(0.0) * scale[column] + offset[column]

    gyro, acc = np.empty((samples, 3)), np.empty((samples, 3))
    for c in range(3):
        scaled(c, gyro[:, c])
        scaled(3 + c, acc[:, c])
    temperature = np.full(samples, np.nan)
    if layout.has_column[6]:
        scaled(6, temperature)
    status = np.zeros(samples, np.int64)
    if layout.has_column[7] and 7 in where:   # an integer bit field: scale and offset do not apply
        k, sig = where[7]
        status[:] = extract(data, frames_of(k), sig)
    return ImuSampleBlock(counters, np.asarray(receive_time_s, dtype=np.float64), gyro, acc, temperature, status,
                          float(rate_hz))


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
    if vi is None and len(first) * n_msgs == m:   # every frame used, in order: strided views, no gathers
        def frames_of(k):
            return slice(k, None, n_msgs)
    else:
        def frames_of(k):
            return first + k if vi is None else vi[first + k]
    last = timestamps[frames_of(n_msgs - 1)]
    counters = rows[complete]
    counters += c0
    return _block(layout, data, frames_of, counters, np.array(last, dtype=np.float64), rate_hz)


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


def frames_from_messages(messages, width: int = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ids, data, lengths, timestamps) arrays for `decode_frames` from python-can `Message`s.

    `width` is the data array's width: 64 holds any CAN FD frame, 8 suffices for classic.
    """

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
