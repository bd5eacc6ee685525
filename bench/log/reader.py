"""Read a run log (MCAP, as written by `bench.log.recorder`) into arrays, tolerating damage.

`read_log(path)` never needs the summary: it walks the records (see `bench.log.mcap.walk`),
checks every chunk's CRC, and reads around damage: a file cut off by a crash gives
everything up to its last complete chunk, a chunk that fails its CRC (or cannot be
decompressed) is skipped and reading resumes after it. `RunLog.scan()` says exactly what
was lost (`damage`; `lost`: byte offsets, log-time ranges, message counts per topic where the
file's message index or summary tells them; `complete` is False when anything was), reading
the frames' chunks no pass has read yet (an explicit call: it can be most of the file);
`read_log(path, scan=True)` does so at once, `RunLog.damage_found` is what is known without
it. A file that is not MCAP at all raises `LogError` with a one-line message naming the file.

The raw CAN frames (`/can/raw`) are the source of truth for IMU data:
`RunLog.imu_samples(layout, rate_hz)` decodes them with the bulk decoder. What reads the file or
parses a topic after `read_log` is a method that says so: the decoded `/imu/samples` topic (possibly
decimated) is parsed by `RunLog.read_imu_records()`, the table states by `RunLog.read_table_states()`
(each once, then kept: a reader that wants the samples does not pay for them; malformed messages found
then are added to the damage), the frames by `read_can_frames()` and `read_can_timestamps_s()` (every
call a pass over the chunks, nothing kept). The recorder writes `/imu/samples` in chunks of their own,
the bulk of a log; `read_log` leaves those compressed and unchecked until `RunLog.read_imu_records()` (or
`RunLog.check_deferred()`) needs them, and adds any damage found then to `damage`
(`read_log(path, defer_samples=False)` checks every chunk at once).
The file is memory-mapped; `/can/raw` batches of one frame length (the usual case) are
unpacked chunk by chunk on worker threads straight into the frame arrays, each chunk freed
as its frames are copied.

A log from outside is hostile: what the reader does for one is bounded (the limits are
module constants). Chunks: see `bench.log.mcap.chunks` (a chunk inflates to exactly what it
declares, at most `MAX_CHUNK_BYTES`; all of a log's chunks to at most its inflate
budget; at most `MAX_RECORDS` records outside chunks). Records and attachments: see
`bench.log.mcap.walk` (`MAX_RECORD_BYTES`, `MAX_ATTACHMENT_BYTES`, `MAX_DBC_BYTES`; the DBC
file the run's metadata names counts as one whatever its name). A CAN record claiming more
than 64 data bytes makes its message malformed. At most `MAX_JSON_MESSAGES` table states
and samples, `MAX_EVENTS` events and `MAX_CHAMBER_STATES` thermal-chamber states
(`RunLog.chamber_states`, parsed with the events); an event or a chamber state whose
fields have the wrong types is malformed (`bench.log.json_topics`). What is refused is
damage, with its reason; a machine that still runs out of memory gives a `LogError`,
never a traceback.
"""

from __future__ import annotations

import mmap
from collections.abc import Generator, Iterator
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from bench.errors import BenchError
from bench.files import InputFileError, open_input
from bench.log.can_stream import decoded_slices, inflated_parts
from bench.log.events import Event
from bench.log.format import (
    CAN_ENCODING,
    FLAG_ERROR,
    FLAG_REMOTE,
    TOPIC_CAN,
    TOPIC_CHAMBER,
    TOPIC_EVENTS,
    TOPIC_SAMPLES,
    TOPIC_STATE,
    decode_can_frames,
    unit_topics,
)
from bench.log.json_topics import (
    MAX_JSON_MESSAGE_BYTES,
    chamber_state_row,
    event_row,
    imu_records_of,
    malformed_damage,
    metadata_damage,
    not_read_damage,
    parse_topic,
    shrink_message,
    table_states_of,
)
from bench.log.mcap import (
    MAX_DBC_BYTES,
    ChannelData,
    Damage,
    InflateBudget,
    MessageCut,
    WalkError,
)
from bench.log.mcap.walk import walk
from bench.log.shared_bus import recorded_share
from bench.log.topic_arrays import ImuRecords, TableStates
from drivers.chamber import ChamberState
from drivers.imu import ImuSampleBlock, ImuStats
from drivers.imu.layout import ImuLayout, default_layout
from drivers.imu.receiver import BusShare
from drivers.imu.stream import StreamDecoder


class LogError(BenchError):
    """The file cannot be read as a run log at all."""


#: Messages of a JSON topic (`/table/state`, `/imu/samples`) parsed at most, and events: a recorded log
#: has about 6 table states a second, one sample per IMU period, and a few events per step. Past these,
#: messages are not read (damage, counted as lost): parsing costs time and memory per message.
MAX_JSON_MESSAGES = 1_000_000
MAX_EVENTS = 100_000
#: the thermal chamber's polled states parsed at most (55 h at one a second; each held as an object)
MAX_CHAMBER_STATES = 200_000
#: the topics a read keeps (the others are only counted)
KEPT_TOPICS = frozenset({TOPIC_CAN, TOPIC_SAMPLES, TOPIC_STATE, TOPIC_EVENTS, TOPIC_CHAMBER})
#: Frames handed to the stream decoder at once (its working arrays are about 100 bytes a frame).
_FEED_FRAMES = 1 << 20
#: the kept JSON topics' long messages are cut as they are gathered (1 MB alarm texts by the thousand took 4.4 GB)
_CUT = MessageCut(frozenset({TOPIC_STATE, TOPIC_EVENTS, TOPIC_CHAMBER}), MAX_JSON_MESSAGE_BYTES, shrink_message)


class CanFrames(NamedTuple):
    """Every `/can/raw` frame of a log (`RunLog.read_can_frames`), as `RunLog.can_pieces` gives them, joined."""

    timestamp_s: np.ndarray   # (n,) float64, the frames' own timestamps (run clock)
    ids: np.ndarray           # (n,) uint32, bit 31 set = extended id
    data: np.ndarray          # (n, 8 or 64) uint8, zero-padded
    lengths: np.ndarray       # (n,) int64 data lengths
    flags: np.ndarray         # (n,) uint8 (FD, BRS, ESI, remote, error: bits as in `bench.log.format`)


@dataclass(frozen=True)
class LogScan:
    """What `RunLog.scan()` found, every chunk of the log looked at."""

    damage: list[str]      # what was lost, one line each (also what reading the states and samples found)
    lost: list[Damage]     # the entries behind `damage`, with offsets and counts
    can_frame_count: int   # frames in `/can/raw` (read)
    non_data_frames: int   # error and remote frames among them (recorded, never decoded)

    @property
    def complete(self) -> bool:
        """True when nothing was lost (the file was closed and every record read)."""
        return not self.damage


@dataclass
class RunLog:
    """Everything read from one run log.

    The raw CAN frames are not held: `imu_samples` decodes them chunk by chunk (each chunk read
    from the file, decompressed, decoded and let go), and so do `can_pieces`, `read_can_frames`,
    `read_can_timestamps_s` and the frame counts. Damage in those chunks is found by the first of them (or by
    `scan()`, which makes sure every chunk was looked at: what was lost, whether the log is complete, the frame
    counts).
    """

    path: str
    metadata: dict[str, dict[str, str]]
    attachments: dict[str, tuple[str, bytes]]
    events: list[Event]
    summary_present: bool
    message_counts: dict[str, int]
    chunks: int
    library: str
    chamber_states: list[ChamberState] = field(default_factory=list)   # `/chamber/state`, a thermal run's
    _damage: list[str] = field(default_factory=list, repr=False)
    _lost: list[Damage] = field(default_factory=list, repr=False)   # the entries behind `damage`, with offsets
    _can: ChannelData | None = field(default=None, repr=False)       # `/can/raw`, chunks mostly deferred
    _samples: ChannelData | None = field(default=None, repr=False)
    _states: ChannelData | None = field(default=None, repr=False)
    _decoded: list = field(default_factory=list, repr=False)   # (layout, rate, window, (block, stats))
    _budget: InflateBudget | None = field(default=None, repr=False)   # what is left for the deferred chunks
    _can_scanned: bool = field(default=False, repr=False)   # every `/can/raw` chunk looked at (damage known)
    _scan_pos: int = field(default=0, repr=False)   # the `/can/raw` parts before this one are counted
    _frame_count: int = field(default=0, repr=False)
    _non_data: int = field(default=0, repr=False)
    _table_states: TableStates | None = field(default=None, repr=False)   # `read_table_states`, once parsed
    _imu_records: ImuRecords | None = field(default=None, repr=False)     # `read_imu_records`, once parsed
    _share: BusShare | None = field(default=None, repr=False)   # a unit on a shared bus: which frames it decodes

    def scan(self) -> LogScan:
        """What was lost and how many frames there are, every `/can/raw` chunk looked at: the chunks no pass
        has read yet are read now (each decompressed and decoded, then let go: once per log, and nothing
        when a decode or a pass over the frames already read them all)."""
        if not self._can_scanned:
            for _ in self.can_pieces():
                pass
        return LogScan(list(self._damage), list(self._lost), self._frame_count, self._non_data)

    @property
    def damage_found(self) -> list[str]:
        """The damage found so far, one line each, without reading the frames' chunks for it (the first pass
        over them, by whatever reads them, adds theirs; `scan()` makes it whole)."""
        return self._damage

    def read_can_timestamps_s(self) -> np.ndarray:
        """Every frame's own timestamp (run clock), float64: one pass over the chunks, 8 bytes a frame (nothing
        kept: a second call reads again)."""
        times = [np.asarray(t, float) for t, *_ in self.can_pieces()]
        return np.concatenate(times) if times else np.zeros(0)

    def read_can_frames(self) -> CanFrames:
        """Every frame at once, as `can_pieces` gives them, joined: one pass over the chunks, 30 to 90 bytes a
        frame (for small logs and tests; large ones go piece by piece; nothing kept)."""
        pieces = list(self.can_pieces())
        if not pieces:
            return CanFrames(*decode_can_frames(None)[0])
        width = max(p[2].shape[1] for p in pieces)
        data = np.zeros((sum(len(p[1]) for p in pieces), width), np.uint8)
        a = 0
        for p in pieces:
            data[a:a + len(p[1]), :p[2].shape[1]] = p[2]
            a += len(p[1])
        return CanFrames(np.concatenate([p[0] for p in pieces]), np.concatenate([p[1] for p in pieces]), data,
                         np.concatenate([p[3] for p in pieces]), np.concatenate([p[4] for p in pieces]))

    def can_pieces(self):
        """The `/can/raw` frames chunk by chunk, in file order: (timestamps s, ids uint32 (bit 31: extended),
        data (n, 8 or 64) uint8 zero-padded, lengths int64, flags uint8 (bits as in `bench.log.format`)).
        Each chunk's damage and counts are recorded the first time a pass reaches it; the caller lets each
        piece go (what is held is a few chunks, not the log)."""
        d = self._can
        if d is None:
            self._can_scanned = True
            return
        for k, answer in inflated_parts(d):
            fresh = k >= self._scan_pos
            if isinstance(answer, Damage):
                if fresh:
                    self._scan_pos = k + 1
                    self._add(answer)
                    d.parts[k], d.lengths[k], d.log_times[k] = None, d.lengths[k][:0], d.log_times[k][:0]
                continue
            # a part's payloads are decoded a slice at a time (a 256 MiB chunk of frames is ~11 M frames: its
            # arrays, and the general route's for mixed lengths, would be several times that at once)
            frames = non_data = bad = 0
            for piece, malformed in decoded_slices(answer, d.lengths[k], d.log_times[k]):
                frames += len(piece[1])
                non_data += int(np.count_nonzero(piece[4] & (FLAG_REMOTE | FLAG_ERROR)))
                bad += malformed
                yield piece
                piece = None   # (the caller's reference is the last: nothing here keeps a chunk's frames)
            answer = None
            if fresh:   # counted once the whole part is through (a pass left half way counts nothing of it)
                self._scan_pos = k + 1
                self._frame_count += frames
                self._non_data += non_data
                if bad:
                    self._add(malformed_damage(TOPIC_CAN, bad))
        self._can_scanned = True

    def read_table_states(self) -> TableStates:
        """The `/table/state` topic as arrays, parsed on the first call and kept (malformed messages are skipped
        and added to the damage, as are those past the first `MAX_JSON_MESSAGES`)."""
        if self._table_states is None:
            found: list[Damage] = []
            self._table_states = table_states_of(self._states, MAX_JSON_MESSAGES, found)
            self._add(*found)
        return self._table_states

    def read_imu_records(self) -> ImuRecords:
        """The `/imu/samples` topic as arrays, its deferred chunks read now (see `check_deferred`); parsed on the
        first call and kept, as `read_table_states`."""
        if self._imu_records is None:
            self.check_deferred()
            found: list[Damage] = []
            self._imu_records = imu_records_of(self._samples, MAX_JSON_MESSAGES, found)
            self._add(*found)
        return self._imu_records

    def imu_samples(self, layout: ImuLayout | None = None, rate_hz: float = 1000.0,
                    reorder_window: int = 8) -> tuple[ImuSampleBlock, ImuStats]:
        """Decode the raw data frames into samples (the source of truth) and link statistics, chunk by
        chunk (memory: the samples, not the frames).

        Error and remote frames are logged but never decoded, as live (`scan().non_data_frames` counts
        them). The decode is kept: solving and the report both ask for it (treat the arrays as
        read-only).
        """
        block, stats, _ = self.imu_samples_visiting(layout, rate_hz, None, reorder_window)
        return block, stats

    def imu_sample_blocks(self, layout: ImuLayout | None = None, rate_hz: float = 1000.0,
                          reorder_window: int = 8) -> Iterator[ImuSampleBlock]:
        """`imu_samples`' samples as blocks in counter order, handed over as the decoder resolves them, chunk
        by chunk (memory: a few chunks, not the samples of the log; nothing is kept: a second call decodes
        again, unless `imu_samples` kept a decode, which is given whole). The blocks joined are exactly
        `imu_samples`' block."""
        kept = self._kept_decode(layout, rate_hz, reorder_window)
        if kept is not None:
            yield kept[0]
            return
        block, _ = yield from self._decode(StreamDecoder(layout, rate_hz, reorder_window), None, hand_over=True,
                                           layout=layout)
        if len(block):
            yield block

    def imu_samples_visiting(self, layout: ImuLayout | None, rate_hz: float, visit,
                             reorder_window: int = 8) -> tuple[ImuSampleBlock, ImuStats, bool]:
        """`imu_samples`, calling `visit(frame times)` with every piece of frames when the decode reads them
        now (one pass over the chunks serves both); the last item says whether it did (not when the decode
        was kept from before)."""
        kept = self._kept_decode(layout, rate_hz, reorder_window)
        if kept is not None:
            return (*kept, False)
        decoding = self._decode(StreamDecoder(layout, rate_hz, reorder_window), visit, hand_over=False, layout=layout)
        while True:   # (nothing is handed over: this runs the decode to its end)
            try:
                next(decoding)
            except StopIteration as done:
                decoded = done.value
                break
        self._decoded.append((layout, rate_hz, reorder_window, decoded))
        return (*decoded, visit is not None)

    def _kept_decode(self, layout: ImuLayout | None, rate_hz: float,
                     reorder_window: int) -> tuple[ImuSampleBlock, ImuStats] | None:
        """The decode `imu_samples` kept for these arguments, if it did."""
        for cached_layout, cached_rate, cached_window, decoded in self._decoded:
            if (cached_layout is layout or cached_layout == layout) and cached_rate == rate_hz \
                    and cached_window == reorder_window:
                return decoded
        return None

    def _decode(self, decoder: StreamDecoder, visit, hand_over: bool,
                layout: ImuLayout | None) -> Generator[ImuSampleBlock, None, tuple[ImuSampleBlock, ImuStats]]:
        """Feed every data frame of `/can/raw` to `decoder`, piece by piece (`visit(frame times)` with each
        piece first, when given): the decoder's answer (`finish()`). `hand_over`: yield the blocks the decoder
        resolves as it goes (they are then not in its answer). On a shared bus, only the unit's own frames (and
        its bus's unknown ids when it is the bus's first unit) are decoded, as live (`bench.log.shared_bus`)."""
        own = np.array(sorted((layout if layout is not None else default_layout()).keys), np.int64)
        try:
            for t, ids, data, lengths, flags in self.can_pieces():
                if visit is not None:
                    visit(t)
                keep = (flags & (FLAG_REMOTE | FLAG_ERROR)) == 0
                mine = self._share.mine(ids.astype(np.int64), own) if self._share is not None else None
                if mine is not None:
                    keep &= mine
                if not keep.all():
                    t, ids, data, lengths = t[keep], ids[keep], data[keep], lengths[keep]
                for a in range(0, len(ids), _FEED_FRAMES):   # a chunk of 256 MiB holds ~11 M frames
                    b = a + _FEED_FRAMES
                    decoder.feed(ids[a:b], data[a:b], lengths[a:b], t[a:b])
                    if hand_over:
                        yield from decoder.take()
                t = ids = data = lengths = flags = keep = None   # let the piece go before the next is read
            return decoder.finish()
        except MemoryError as exc:
            raise LogError(f"{self.path}: not enough memory to decode its CAN frames") from exc

    @property
    def unchecked_chunks(self) -> int:
        """`/imu/samples` chunks not decompressed (nor CRC-checked) yet: see `check_deferred`."""
        return self._samples.deferred_chunks if self._samples is not None else 0

    def check_deferred(self) -> list[str]:
        """Decompress and check the deferred `/imu/samples` chunks; returns (and adds to `damage`)
        what was lost in them."""
        if self._samples is None or not self.unchecked_chunks:
            return []
        found = self._samples.inflate_deferred(TOPIC_SAMPLES, self._budget)
        self._add(*found)
        return [d.describe() for d in found]

    def _add(self, *found: Damage) -> None:
        """Damage found after `read_log`: into `lost` and `damage` alike."""
        for damage in found:
            self._lost.append(damage)
            self._damage.append(damage.describe())

    def summary(self, read_frames: bool = True) -> str:
        """One line: what the log holds and whether anything was lost. `read_frames=False`: without reading the
        frames' chunks for it (the frames as recorded, the damage found so far), for a caller about to read them."""
        if read_frames:
            scan = self.scan()
            frames = f"{scan.can_frame_count} CAN frames"
            state = "complete" if scan.complete else f"DAMAGED ({len(scan.damage)} problems)"
        else:
            frames = f"{self.message_counts.get(TOPIC_CAN, 0)} batches of CAN frames recorded"
            found = self.damage_found
            state = f"DAMAGED ({len(found)} problems so far)" if found else "no damage found so far"
        unchecked = (f" ({self.unchecked_chunks} {TOPIC_SAMPLES} chunks, derived from {TOPIC_CAN}, not read)"
                     if self.unchecked_chunks else "")
        return (f"{self.path}: {frames}, {len(self.read_table_states())} table states, "
                f"{len(self.events)} events, {self.chunks} chunks{unchecked}; {state}")


class _FileSource:
    """Reads spans of a log file again when a deferred chunk is needed (the walk keeps no copy). The
    chunk's CRC and framing are checked on every read, as the first time."""

    def __init__(self, path: str):
        self.path = path

    def __call__(self, offset: int, length: int) -> bytes:
        with open_input(self.path, max_bytes=None, what="run log") as f:
            f.seek(offset)
            return f.read(length)


def _map_file(path: str):
    """The file's bytes, memory-mapped (no copy; the walk reads each byte about once)."""
    try:
        with open_input(path, max_bytes=None, what="run log") as f:   # a regular file: never a FIFO or a device
            try:
                return mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
            except (ValueError, OSError):   # empty, or a file that cannot be mapped: read it
                return f.read()
    except InputFileError as exc:
        raise LogError(str(exc)) from exc
    except OSError as exc:
        raise LogError(f"{path}: cannot read: {exc.strerror or exc}") from exc


def read_log(path, *, defer_samples: bool = True, messages: bool = True, scan: bool = False,
             unit: str | None = None) -> RunLog:
    """Read a run log; see the module docstring for how damage is handled and what `defer_samples` does.
    `messages=False`: the records and metadata only (no table states, events, frames or samples are kept:
    what a catalogue of logs needs, at a fraction of the memory). `scan`: `RunLog.scan()` before returning.
    `unit`: the serial of a unit of a run of several IMUs (not its reference unit): the log read with that unit's
    frames and samples (`bench.log.format.unit_topics`) where a single IMU's are."""
    path = str(path)
    try:
        log = _read_log(path, defer_samples, messages, unit)
        if scan:
            log.scan()
        return log
    except MemoryError as exc:   # within the reader's limits, but more than this machine has
        raise LogError(f"{path}: not enough memory to read it") from exc


def _read_log(path: str, defer_samples: bool, messages: bool = True, unit: str | None = None) -> RunLog:
    can_topic, samples_topic = unit_topics(unit) if unit is not None else (TOPIC_CAN, TOPIC_SAMPLES)
    kept = (KEPT_TOPICS - {TOPIC_CAN, TOPIC_SAMPLES}) | {can_topic, samples_topic}
    buf = _map_file(path)
    try:
        # /can/raw chunks are streamed (`RunLog.can_pieces`), /imu/samples ones inflated when first asked
        # for; neither is held meanwhile: both are read from the file again
        # (with a source, no decompressed chunk outlives its gathering: the topics not read are only counted,
        # the table states and events copied out up to what is parsed, the frames and samples left in the file)
        w = walk(buf, defer_topics=frozenset({can_topic, samples_topic} if defer_samples else {can_topic}),
                 source=_FileSource(path),
                 keep_topics=frozenset(kept if messages else ()),
                 keep_limits={TOPIC_STATE: MAX_JSON_MESSAGES, TOPIC_EVENTS: MAX_EVENTS,
                              TOPIC_CHAMBER: MAX_CHAMBER_STATES},
                 cut=_CUT)
    except WalkError as exc:
        raise LogError(f"{path}: {exc}") from exc
    finally:
        if isinstance(buf, mmap.mmap):
            try:
                buf.close()
            except BufferError:   # a view is still alive somewhere: the mapping goes when it does
                pass
        del buf

    by_topic: dict[str, ChannelData] = {}
    counts: dict[str, int] = {}
    for ch, d in w.data.items():
        topic = w.topic(ch)
        counts[topic] = counts.get(topic, 0) + len(d) + d.not_kept + d.over_limit
        channel = w.channels.get(ch)
        if channel is not None and topic == can_topic and channel.message_encoding != CAN_ENCODING:
            raise LogError(f"{path}: {can_topic} has message encoding {channel.message_encoding!r}, "
                           f"expected {CAN_ENCODING!r}")
        by_topic[topic] = d
    damage = list(w.damage)
    dbc = w.metadata.get("imu", {}).get("dbc")   # the DBC file the run names, whatever its name ends with
    if dbc in w.attachments and len(w.attachments[dbc][1]) > MAX_DBC_BYTES:
        damage.append(Damage("attachment", w.attachment_offsets.get(dbc, 0),
                             f"attachment {dbc[:64]!r} (the run's DBC file) holds {len(w.attachments[dbc][1])} bytes, "
                             f"more than a DBC file may ({MAX_DBC_BYTES} bytes); dropped"))
        del w.attachments[dbc]
    damage += metadata_damage(w.metadata)

    # The summary's statistics tell how many messages each channel should have.
    if w.statistics is not None:
        known_lost: dict[str, int] = {}
        for dmg in damage:
            for topic, n in dmg.lost.items():
                known_lost[topic] = known_lost.get(topic, 0) + n
        for ch, expected in w.statistics.channel_message_counts.items():
            topic = w.topic(ch)
            missing = expected - counts.get(topic, 0) - known_lost.get(topic, 0)
            if missing > 0:
                damage.append(Damage("message", w.size, f"the summary counts {missing} more messages on {topic} "
                                                        f"than were read"))

    # Only what is kept may keep the decompressed chunks alive: the other topics go, the table states are
    # joined (small); the CAN frames are read chunk by chunk when asked for (`RunLog.can_pieces`).
    by_topic = {t: d for t, d in by_topic.items() if t in kept}
    w.data.clear()
    if TOPIC_STATE in by_topic:
        skipped = by_topic[TOPIC_STATE].keep_first(MAX_JSON_MESSAGES) + by_topic[TOPIC_STATE].over_limit
        if skipped:
            damage.append(not_read_damage(TOPIC_STATE, skipped, MAX_JSON_MESSAGES))
        by_topic[TOPIC_STATE].compact()

    events = (parse_topic(by_topic.pop(TOPIC_EVENTS), TOPIC_EVENTS, MAX_EVENTS, event_row, damage)
              if TOPIC_EVENTS in by_topic else [])
    chamber_states = (parse_topic(by_topic.pop(TOPIC_CHAMBER), TOPIC_CHAMBER, MAX_CHAMBER_STATES, chamber_state_row,
                                  damage) if TOPIC_CHAMBER in by_topic else [])

    library = w.header.library if w.header is not None else ""
    return RunLog(path=path, metadata=w.metadata, attachments=w.attachments, events=events,
                  chamber_states=chamber_states,
                  summary_present=w.footer is not None and w.statistics is not None,
                  message_counts=counts, chunks=w.chunks, library=library,
                  _damage=[d.describe() for d in damage], _lost=damage, _can=by_topic.get(can_topic),
                  _samples=by_topic.get(samples_topic), _states=by_topic.get(TOPIC_STATE), _budget=w.budget,
                  _share=recorded_share(w.metadata, unit))


__all__ = ["CanFrames", "ImuRecords", "LogError", "LogScan", "RunLog", "TableStates", "read_log"]
