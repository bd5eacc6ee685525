"""The IMU frame rules, once: what makes a frame usable and how frames become samples.

The bulk decoder (`drivers.imu.bulk.decode_frames`, a whole recording at once) and the stream decoder
(`drivers.imu.stream.StreamDecoder`, frames piece by piece: a log chunk by chunk, the live receiver poll
by poll) both apply these rules with the array functions below, and the tests hold the two to the same
samples and counts whatever the cuts:
1. A frame is checked in order: known id, expected length, CRC. A failure is counted
   (unknown_id, wrong_length, crc_errors) and the frame is not used: its counter cannot
   be trusted, so its sample ends up incomplete.
2. Each valid frame's counter is unwrapped relative to the previous valid frame's
   (a step of more than half the counter range backwards counts as going back), so a
   16-bit counter becomes a monotonically increasing int64 sample index. The first
   valid frame's raw counter is the start.
3. `head` is the newest counter seen. A frame is late (counted, not used) if its counter
   is at or below head - reorder_window, or before the start; its sample was already
   resolved. A second frame for the same counter and id is a duplicate (counted, first
   kept). A used frame whose counter is below head is out_of_order (still used).
4. A counter leaves the window when head reaches counter + reorder_window: with every
   mapped frame it is a sample, with some it is an incomplete sample (dropped, counted),
   with none it is a counter gap (counted per missing sample). Samples leave in counter
   order. The first counter's sample, incomplete, is counted as joined mid-sample
   instead: its first frames went out before the bench started listening, which loses
   nothing it could have had. At the end of a stream everything still pending is
   resolved; there the newest counter's sample, incomplete, is counted as left
   mid-sample (its last frames went out after the bench stopped listening), not as lost.
A time-stamped layout (sbg-ecan) has its frames numbered first (`drivers.imu.numbering`).
"""

from __future__ import annotations

import functools
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from drivers.errors import ImuFrameError
from drivers.imu.crc import crc8_columns, crc8_raw, id_bytes, linear_crc
from drivers.imu.layout import EXTENDED_ID_FLAG, ImuLayout, SignalLayout
from drivers.imu.samples import ImuSampleBlock


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


def as_arrays(ids, data, lengths, timestamps):
    """The frames as checked arrays: ids (n,), data (n, width >= 8) C-contiguous uint8, lengths (n,) and
    timestamps (n,) (defaults: the width, 0.0); `ImuFrameError` for arrays of the wrong kind."""
    try:
        ids = np.asarray(ids)
        data = np.asarray(data)
        if ids.ndim != 1 or (len(ids) and ids.dtype.kind not in "iu"):   # (np.issubdtype: slower)
            raise ImuFrameError(f"ids must be a 1-D integer array, got shape {ids.shape} {ids.dtype}")
        if data.ndim != 2 or data.dtype != np.uint8:
            raise ImuFrameError(f"data must be a 2-D uint8 array (frames x bytes), got {data.shape} {data.dtype}")
        n, width = data.shape
        if len(ids) != n:
            raise ImuFrameError(f"{len(ids)} ids for {n} frames of data")
        lengths = np.full(n, width, np.int64) if lengths is None else np.asarray(lengths)
        if lengths.shape != (n,) or (n and lengths.dtype.kind not in "iu"):
            raise ImuFrameError(f"lengths must be {n} integers, got {lengths.shape} {lengths.dtype}")
        if n and (np.minimum.reduce(lengths) < 0 or np.maximum.reduce(lengths) > width):
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


class FrameScreen:
    """Rules 1 and 2 for one layout (which frames are usable, and their counters), its tables built once."""

    def __init__(self, layout: ImuLayout):
        self.layout = layout
        msgs = layout.messages
        self._keys = keys = layout.keys
        # one counter signal read from every frame at once when all messages hold it in the same bits
        self._counter = msgs[0].counter if same_signal([m.counter for m in msgs]) else None
        self._dtype = np.int8 if len(keys) < 127 else np.int32
        self._top = max(keys)
        self._lut: np.ndarray | None = None
        if self._top < (1 << 16):
            # one gather through a table of every id up to the largest key
            self._lut = np.full(self._top + 2, -1, self._dtype)
            for k, key in enumerate(keys):
                self._lut[key] = k
        self._expected = np.array([m.length for m in msgs], np.int64)
        self._one_length = int(self._expected[0]) if (self._expected == self._expected[0]).all() else None
        shapes = {(m.length, m.crc_byte) for m in msgs}
        length, crc_byte = next(iter(shapes))
        self._crc_byte = crc_byte
        self._tables: list[tuple[int, np.ndarray]] = []
        self._id_const = np.zeros(0, np.uint8)
        if len(shapes) == 1 and crc_byte is None:
            self._crc_mode = "none"
        elif len(shapes) == 1 and length <= 8:
            # every frame at once: the CRC is affine in the data bits, 4 lookups of 16 bits each
            self._crc_mode = "linear"
            lin = linear_crc(length, crc_byte)
            self._tables = [(first_bit // 16, table) for first_bit, table in lin.tables_np]
            self._id_const = np.array([lin.id_constant(m.frame_id, m.is_extended_id) for m in msgs] + [0], np.uint8)
        else:
            self._crc_mode = "per message"

    def screen(self, ids: np.ndarray, data: np.ndarray, lengths: np.ndarray):
        """Message index (-1: unknown id), validity (known id, right length, CRC good) and the counts, for
        arrays as `as_arrays` gives them.

        Returns (msg_index, valid, known frames, frames of the right length)."""
        keys, n, dtype, top = self._keys, len(ids), self._dtype, self._top
        lut = self._lut if n and (ids.dtype.kind == "u" or int(np.minimum.reduce(ids)) >= 0) else None
        expected, one_length, crc_mode = self._expected, self._one_length, self._crc_mode
        tables, id_const, crc_byte = self._tables, self._id_const, self._crc_byte

        def screen_block(a: int) -> tuple[np.ndarray, np.ndarray, int, int]:
            b = min(n, a + _BLOCK)
            if lut is not None:
                mi = lut.take(np.minimum(ids[a:b], top + 1))   # (take: faster than indexing)
            else:
                mi = np.full(b - a, -1, dtype)
                for k, key in enumerate(keys):
                    mi[ids[a:b] == key] = k
            known = mi >= 0
            if one_length is not None:
                ok = known & (lengths[a:b] == one_length)
            else:
                ok = known & (lengths[a:b] == expected[np.maximum(mi, 0)])
            n_known, n_ok = int(np.count_nonzero(known)), int(np.count_nonzero(ok))
            if crc_mode == "linear":
                chunks = data[a:b, :8].view("<u2")
                crc = id_const.take(mi)   # (mi -1, an unknown id: the table's last entry)
                for column, table in tables:
                    crc ^= table.take(chunks[:, column])
                ok &= crc == data[a:b, crc_byte]
            return mi, ok, n_known, n_ok

        blocks = range(0, n, _BLOCK)
        if len(blocks) <= 1:   # a poll's batch
            msg_index, valid, n_known, n_length_ok = screen_block(0)
        else:
            if len(blocks) >= _PARALLEL_BLOCKS and _WORKERS > 1:
                # numpy releases the GIL in these block operations: the blocks screen on every core
                with ThreadPoolExecutor(_WORKERS, thread_name_prefix="imu-screen") as pool:
                    screened = list(pool.map(screen_block, blocks))
            else:
                screened = [screen_block(a) for a in blocks]
            msg_index = np.concatenate([mi for mi, _, _, _ in screened])
            valid = np.concatenate([ok for _, ok, _, _ in screened])
            n_known = sum(k for _, _, k, _ in screened)
            n_length_ok = sum(k for _, _, _, k in screened)
        if crc_mode == "per message":
            valid = check_crcs(data, msg_index, valid, self.layout)
        return msg_index, valid, n_known, n_length_ok

    def counters(self, data: np.ndarray, msg_index: np.ndarray, valid: np.ndarray, vi) -> np.ndarray:
        """Raw counter values of the valid frames (`vi`, None when every frame is valid), in frame order."""
        if self._counter is not None:
            c = extract_all(data, self._counter)
            return c if vi is None else c[vi]
        counter_raw = np.zeros(len(msg_index), np.int64)
        for k, m in enumerate(self.layout.messages):
            rows = np.flatnonzero(valid & (msg_index == k))
            counter_raw[rows] = extract(data, rows, m.counter)
        return counter_raw if vi is None else counter_raw[vi]


def same_signal(sigs) -> bool:
    """True when the signals sit in the same bits of their frames (names aside)."""
    first = sigs[0]
    return all((s.length, s.signed, s.big_endian, s.shift, s.first_byte, s.last_byte, s.window_shift)
               == (first.length, first.signed, first.big_endian, first.shift, first.first_byte, first.last_byte,
                   first.window_shift) for s in sigs)


@functools.lru_cache(maxsize=256)
def _whole_integer_dtype(sig: SignalLayout) -> np.dtype | None:
    """The dtype reading `sig` as a whole byte-aligned integer of 1, 2, 4 or 8 bytes, or None (cached: a poll
    asks for it every time)."""
    nbytes = sig.last_byte - sig.first_byte + 1
    if sig.length == 8 * nbytes and nbytes in (1, 2, 4, 8) and sig.window_shift == 0:
        return np.dtype(f"{'>' if sig.big_endian else '<'}{'i' if sig.signed else 'u'}{nbytes}")
    return None


def extract_all(data: np.ndarray, sig: SignalLayout) -> np.ndarray:
    """Raw values of `sig` in every row; a zero-copy view when it is a whole byte-aligned integer."""
    dtype = _whole_integer_dtype(sig)
    if dtype is not None:
        return np.ndarray((data.shape[0],), dtype=dtype, buffer=data, offset=sig.first_byte,
                          strides=(data.shape[1],))
    return extract(data, slice(None), sig)


def check_crcs(data: np.ndarray, msg_index: np.ndarray, length_ok: np.ndarray, layout: ImuLayout) -> np.ndarray:
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


def unwrap_steps(c: np.ndarray, counter_bits: int) -> np.ndarray:
    """Differences of consecutive counters, wrapped into -modulus/2 .. modulus/2 - 1."""
    if c.dtype.kind == "u" and c.dtype.itemsize * 8 == counter_bits:
        # unsigned subtraction wraps by itself; read as signed it is the shortest step
        return (c[1:] - c[:-1]).view(f"i{c.dtype.itemsize}")   # (np.diff: the same, with more overhead)
    modulus = 1 << counter_bits
    # Bound to a name first: written inline, mypy typed np.diff(...) with numpy's datetime64 overload
    # (a timedelta64 result, which has no `&`); the values are int64 either way.
    c64 = c.astype(np.int64)
    d = np.diff(c64) & (modulus - 1)
    d[d >= modulus >> 1] -= modulus
    return d


def _view_dtype(sig: SignalLayout) -> np.dtype | None:
    """The typed view that reads `sig` with no shifts (a whole byte-aligned integer of 1, 2 or 4 bytes), or None."""
    nbytes = sig.last_byte - sig.first_byte + 1
    if sig.length == 8 * nbytes and nbytes in (1, 2, 4) and sig.window_shift == 0:
        return np.dtype(f"{'>' if sig.big_endian else '<'}{'i' if sig.signed else 'u'}{nbytes}")
    return None


def signal_values(data: np.ndarray, rows, sig: SignalLayout, dtype: np.dtype | None = None) -> np.ndarray:
    """Raw values of `sig` in `data[rows]`: a view (typed, no shifts) for a whole byte-aligned integer
    (`dtype`: its `_view_dtype`, when known), else as `extract` gives them."""
    dtype = dtype if dtype is not None else _view_dtype(sig)
    if dtype is not None:
        view = np.ndarray((data.shape[0],), dtype=dtype, buffer=data, offset=sig.first_byte,
                          strides=(data.shape[1],))
        return view[rows]
    return extract(data, rows, sig)


class SampleColumns:
    """Rule 4's output for one layout: where each column of a sample lies in its frames, worked out once."""

    def __init__(self, layout: ImuLayout):
        self.layout = layout
        where = {column: (k, sig) for k, m in enumerate(layout.messages) for column, sig in m.values}
        #: the float columns: 0..5 (gyro, acc) and 6 (temperature) if the layout has one
        self._n_float = 7 if layout.has_column[6] else 6
        #: (column, message, signal, view dtype) of each float column a message holds; the others read 0
        self._sources = [(column, *where[column], _view_dtype(where[column][1]))
                         for column in range(self._n_float) if column in where]
        self._absent = [column for column in range(self._n_float) if column not in where]
        self._scale = np.array(layout.scale[:self._n_float], np.float64)
        self._offset = np.array(layout.offset[:self._n_float], np.float64)
        # an integer bit field: scale and offset do not apply
        self._status = where[7] if layout.has_column[7] and 7 in where else None
        self._status_dtype = _view_dtype(self._status[1]) if self._status is not None else None
        self._runs_of_width: dict[int, list[tuple[int, int, np.dtype, int, int]] | None] = {}

    def _runs(self, width: int) -> list[tuple[int, int, np.dtype, int, int]] | None:
        """For frames `width` bytes wide, a sample's frames side by side (one row of messages x width bytes):
        runs of consecutive float columns read with one view each, (first column, columns, dtype, byte of the
        first, bytes between columns), and the status as (-1, 1, dtype, byte, 0); None when a signal is not
        a whole byte-aligned integer (read column by column then)."""
        if width in self._runs_of_width:
            return self._runs_of_width[width]
        runs: list[tuple[int, int, np.dtype, int, int]] | None = []
        sources = [(column, k * width + sig.first_byte, dtype) for column, k, sig, dtype in self._sources]
        if self._status is not None:
            k, sig = self._status
            sources.append((-1, k * width + sig.first_byte, self._status_dtype))
        for column, at, dtype in sources:
            if dtype is None:
                runs = None
                break
            assert runs is not None
            if runs and column >= 0:
                first, count, run_dtype, run_at, step = runs[-1]
                if (first >= 0 and run_dtype == dtype and column == first + count
                        and (at - run_at == count * step if count > 1 else at > run_at)):
                    runs[-1] = (first, count + 1, dtype, run_at, (at - run_at) // count)
                    continue
            runs.append((column, 1, dtype, at, 0))
        self._runs_of_width[width] = runs
        return runs

    def block(self, data: np.ndarray, frames_of, counters: np.ndarray, receive_time_s: np.ndarray,
              rate_hz: float) -> ImuSampleBlock:
        """The samples straight from the frames, `frames_of(k)` indexing message k's frame of every sample
        (None: `data` holds exactly every sample's frames, in message order): exactly `ImuSampleBlock.from_raw`
        of the raw values (raw * scale + offset in float64), without its int64 intermediate; all columns
        scaled at once (a poll's few samples: few numpy calls)."""
        samples = len(counters)
        values = np.empty((samples, self._n_float))
        status = np.zeros(samples, np.int64)
        runs = None
        if frames_of is None and data.flags.c_contiguous and len(data) == samples * len(self.layout.messages):
            runs = self._runs(data.shape[1])
        if runs is not None:
            # a sample's frames side by side are one wide row: columns at evenly spaced bytes of it read
            # through one strided view
            row = data.shape[1] * len(self.layout.messages)
            for first, count, run_dtype, at, step in runs:
                view = np.ndarray((samples, count), dtype=run_dtype, buffer=data, offset=at, strides=(row, step))
                if first < 0:
                    status[:] = view[:, 0]
                else:
                    values[:, first:first + count] = view
        elif frames_of is None:
            n_msgs = len(self.layout.messages)

            def frames_of(k):
                return slice(k, None, n_msgs)
        if runs is None:
            for column, k, sig, dtype in self._sources:
                values[:, column] = signal_values(data, frames_of(k), sig, dtype)
            if self._status is not None:
                k, sig = self._status
                status[:] = signal_values(data, frames_of(k), sig, self._status_dtype)
        for column in self._absent:
            values[:, column] = 0.0
        values *= self._scale
        values += self._offset
        temperature = values[:, 6].copy() if self._n_float == 7 else np.full(samples, np.nan)
        return ImuSampleBlock(counters, np.asarray(receive_time_s, dtype=np.float64), values[:, 0:3].copy(),
                              values[:, 3:6].copy(), temperature, status, float(rate_hz))


def frames_from_messages(messages, width: int | None = 64) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(ids, data, lengths, timestamps) arrays for the decoders from python-can `Message`s.

    `width` is the data array's width: 64 holds any CAN FD frame, 8 suffices for classic; None: the
    longest frame's, at least 8.
    """
    messages = list(messages)
    n = len(messages)
    flag = EXTENDED_ID_FLAG
    ids = np.array([m.arbitration_id | flag if m.is_extended_id else m.arbitration_id for m in messages], np.int64)
    sizes = [len(m.data) for m in messages]
    lengths = np.array(sizes, np.int64)
    longest = max(sizes, default=0)
    if width is None:
        width = max(8, longest)
    elif longest > width:
        raise ImuFrameError(f"a frame of {longest} bytes does not fit a data width of {width}")
    timestamps = np.array([m.timestamp for m in messages], np.float64)
    if n and min(sizes) == width:   # every frame as wide as the array (the usual batch): their bytes joined
        buf = bytearray().join([m.data for m in messages])
    else:
        buf = bytearray(n * width)
        for i, m in enumerate(messages):
            buf[i * width:i * width + len(m.data)] = m.data
    return ids, np.frombuffer(buf, np.uint8).reshape(n, width), lengths, timestamps

__all__ = ["FrameScreen", "SampleColumns", "as_arrays", "check_crcs", "extract", "extract_all", "frames_from_messages",
           "same_signal", "signal_values", "unwrap_steps"]
