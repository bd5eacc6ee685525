"""The `/can/raw` parts of a run log streamed in order: each read and decompressed on a worker thread ahead of the
one being decoded, then decoded into frame arrays a slice at a time (what `bench.log.reader.RunLog.can_pieces`
builds on)."""

from __future__ import annotations

from collections import deque
from concurrent.futures import Future, ThreadPoolExecutor

import numpy as np

from bench.log.format import TOPIC_CAN, decode_can_frames
from bench.log.mcap import ChannelData, ChunkRefused, Damage, InChunk, Part, inflated_or_refusal
from bench.log.threads import reader_threads

#: Payload bytes of a `/can/raw` part decoded into frame arrays at once.
SLICE_BYTES = 32 << 20
#: Declared bytes of `/can/raw` chunks decompressed ahead of the one being decoded (at least one chunk).
STREAM_AHEAD_BYTES = 96 << 20


def decoded_slices(part: Part, lengths: np.ndarray, log_times: np.ndarray):
    """(frames, malformed count) of a part's payloads, at most `SLICE_BYTES` of payloads at a time."""
    data, starts = part.located(lengths)
    ends = np.cumsum(lengths)
    a = 0
    while a < len(lengths):
        b = max(a + 1, int(np.searchsorted(ends, ends[a] - lengths[a] + SLICE_BYTES, side="right")))
        yield decode_can_frames(ChannelData([InChunk(data, starts[a:b])], [lengths[a:b]], [log_times[a:b]]),
                                release=True)
        a = b


def inflated_parts(d: ChannelData):
    """(part index, (frames, malformed) or `Damage`) for every part of `d` still there, in order; the next
    parts are read and decompressed on a worker thread while the caller decodes (zstd releases the GIL).
    (What they may inflate to was counted by the walk.)"""
    todo = [k for k, p in enumerate(d.parts) if p is not None]
    threads = reader_threads(2)
    pool = ThreadPoolExecutor(threads, thread_name_prefix="can-stream") if len(todo) > 1 and threads > 1 else None
    ahead: deque = deque()   # (k, future or answer, declared bytes)
    in_flight, nxt = 0, 0
    try:
        while ahead or nxt < len(todo):
            while nxt < len(todo) and (not ahead or in_flight < STREAM_AHEAD_BYTES):
                k = todo[nxt]
                nxt += 1
                part = d.parts[k]
                size = part.declared_bytes(d.lengths[k])
                # a deferred chunk is read and decompressed first, on a worker thread
                job = pool.submit(inflated_or_refusal, part) if pool is not None else inflated_or_refusal(part)
                ahead.append((k, job, size))
                in_flight += size
            k, job, size = ahead.popleft()
            in_flight -= size
            answer = job.result() if isinstance(job, Future) else job
            del job   # (a finished future holds its result: the caller's piece must be the only reference)
            if isinstance(answer, ChunkRefused):
                part = d.parts[k]
                answer = Damage("chunk", part.offset, str(answer), part.start_ns, part.end_ns,
                                {TOPIC_CAN: len(part.offsets)})
            yield k, answer
            answer = None
    finally:
        if pool is not None:
            for _, job, _ in ahead:
                if isinstance(job, Future):
                    job.cancel()
            pool.shutdown(wait=True)
