"""Fuzzing the log reader (issue 13): whatever a log holds, reading it returns or raises `LogError`.

A small real log is recorded once per module with `McapRecorder` (frames, samples, table
states, events, a DBC attachment; one chunk per batch) in each compression. Hypothesis
(derandomized: CI sees the same examples every time) applies one to three mutations:
truncation, byte flips, a forged record length, a forged chunk field (uncompressed
size, compression, data length), a forged message index entry, a forged CAN length byte
inside a chunk, or a message's content replaced by well-framed hostile content (a CAN
record claiming up to 255 data bytes and holding them; JSON fields of odd types, huge
integers, 1e308, arrays nested 100,000 deep), the chunk recompressed honestly so the
decoders see it (`tests.helpers.mcap_surgery.mutate`). Then `read_log` and everything a
reader touches (`table_states`, `imu_records`, `imu_samples()`, `events`) must return,
or `read_log` raise `LogError` with one line; anything else is a bug. The whole test
takes a few seconds.
"""

from __future__ import annotations

import functools
import tempfile
from pathlib import Path

import can
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from bench.log.events import make_event
from bench.log.reader import LogError, read_log
from bench.log.recorder import McapRecorder
from drivers.imu import ImuEncoder, decode_frames, default_layout
from drivers.turntable.base import AxisMode, AxisState, AxisStatus, TableState
from tests.helpers.mcap_surgery import FORGED, KINDS, mutate

LAYOUT = default_layout()
RATE_HZ = 1000.0


class _Clock:
    t = 0.0

    def __call__(self) -> float:
        return self.t


def _record(path, compression: str) -> bytes:
    clock = _Clock()
    rec = McapRecorder(path, clock=clock, compression=compression,
                       metadata={"run": {"run_id": "fuzz"}, "imu": {"dbc": "imu.dbc", "rate_hz": "1000"}})
    rec.on_event(make_event(0.0, "transition", "start", state="running", data={"from": "idle"}))
    rng = np.random.default_rng(0)
    for b in range(6):
        counters = np.arange(10 * b, 10 * b + 10)
        frames = ImuEncoder(LAYOUT).encode(counters, rng.normal(0, 3000, (10, 3)), rng.normal(0, 40, (10, 3)))
        times = (frames.sample + 1) / RATE_HZ
        rec.on_can_frames([can.Message(timestamp=float(times[i]), arbitration_id=int(frames.ids[i]),
                                       is_extended_id=False, data=frames.data[i, :frames.lengths[i]].tobytes())
                           for i in range(len(frames))])
        block, _ = decode_frames(frames.ids, frames.data, frames.lengths, times, layout=LAYOUT, rate_hz=RATE_HZ)
        rec.on_imu(block)
        axes = tuple(AxisState(10.0 * b + j, 0.5, AxisMode.POSITION, AxisStatus.ENABLED) for j in range(3))
        rec.on_table_state(TableState(float(times[-1]), axes, ""))
        step = {"kind": "dwell", "angles_deg": [0.0, 90.0, 0.0]}
        rec.on_event(make_event(float(times[0]), "step_started", "dwell", step_index=b, step_unit=f"P{b:02d}",
                           data={"step": step}))
        rec.on_event(make_event(float(times[-1]), "step_finished", "dwell done", step_index=b, step_unit=f"P{b:02d}",
                           data={"step": step, "counter_first": int(counters[0]), "counter_last": int(counters[-1])}))
        clock.t += 1.5   # past the chunk interval: every batch ends its chunk
    rec.add_attachment("imu.dbc", "text/plain", b"VERSION \"\"\n")
    rec.close()
    return path.read_bytes()


@functools.cache
def base_log(compression: str) -> bytes:
    """The small log in `compression`, recorded once (a cache, not a fixture: hypothesis would print it)."""
    with tempfile.TemporaryDirectory() as folder:
        return _record(Path(folder) / "base.mcap", compression)


mutations = st.lists(st.tuples(st.sampled_from(KINDS), st.floats(0, 1, exclude_max=True),
                               st.one_of(st.sampled_from(FORGED), st.integers(0, (1 << 64) - 1)),
                               st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(1, 255)),
                                        min_size=1, max_size=6)),
                     min_size=1, max_size=3)


@pytest.mark.slow
@settings(max_examples=150, deadline=2000, derandomize=True,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(compression=st.sampled_from(["zstd", "lz4", "none"]), steps=mutations)
def test_a_mutated_log_reads_or_raises_log_error(tmp_path, compression, steps):
    data = base_log(compression)
    for kind, where, value, flips in steps:
        data = mutate(data, kind, where, value, flips)
    path = tmp_path / "fuzz.mcap"
    path.write_bytes(data)
    try:
        log = read_log(path)
    except LogError as exc:
        assert "\n" not in str(exc)
        return
    assert len(log.read_table_states()) <= 6 and len(log.events) <= 13
    assert len(log.read_imu_records()) <= 60
    log.imu_samples()
    assert all(isinstance(d, str) and "\n" not in d for d in log.scan().damage)
    assert log.summary()


def test_the_unmutated_logs_read_whole(tmp_path):
    for compression in ("zstd", "lz4", "none"):
        path = tmp_path / f"{compression}.mcap"
        path.write_bytes(base_log(compression))
        log = read_log(path)
        assert log.scan().complete, (compression, log.scan().damage)
        assert len(log.read_table_states()) == 6 and len(log.events) == 13 and len(log.read_imu_records()) == 60
        assert len(log.imu_samples()[0].counter) == 60
