"""The noise characterisation of a recorded static dwell (`bench noise LOG`, a `static-noise` run).

The samples are the raw CAN frames decoded with the DBC and signal mapping recorded in
the log (as `bench solve` does), cut to the longest finished dwell's counter window
(the sequencer records it in the step's `step_finished` event); a counter gap splits
the window and the longest gap-free stretch is analysed (a note says so). Outputs
become input units with scale factors from, in this order: a calibration result
(`calibration`: Kg, Ka per axis), the simulated IMU's truth when the log is of a
simulated run, or nothing (`NoiseInputError`: a hardware log needs a calibration for
its gyro scale; the noise is added on the input side, so dividing by the scale is exact
for a sensor's own noise).

`analyse_log` (what `bench noise LOG` and a static-noise `bench run` use) streams: the
frames are decoded chunk by chunk on the calling thread while a worker turns the samples
into the Allan phase, so only the phase of the dwell is held, never the log's decoded
samples. `static_record` decodes the whole log first: the reference the stream is tested
against (bit for bit without counter gaps).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.errors import InputError
from bench.log.events import DwellRecord, finished_observation_steps
from bench.log.names import run_id_of
from bench.log.reader import LogError, RunLog, read_log
from bench.log.run_info import layout_and_config_from_log
from bench.model.imu import ImuCoefficients
from bench.model.noise_result import CHANNELS, NoiseResult
from bench.model.units import DEG_PER_HOUR, MICRO_G
from bench.noise.allan import PhaseAccumulator
from bench.noise.fit import MIN_RECORD_SAMPLES
from bench.noise.result import analyse_phase
from bench.noise.simulate import counts_to_allan_units
from drivers.imu import ImuSampleBlock
from drivers.imu.layout import ImuLayout

#: A dwell shorter than this many samples is too short for the noise analysis (`bench.noise.fit`).
MIN_SAMPLES = MIN_RECORD_SAMPLES


class NoiseInputError(InputError):
    """A log the noise characterisation cannot use (no dwell, too short, no scale factors)."""


#: Samples per block handed to the Allan accumulator (6 channels x 8 bytes: 12 MB of float64 at a time).
BLOCK_SAMPLES = 1 << 18
#: Decoded samples the reading thread hands the phase thread at a time, and the hand-overs that may wait.
_HAND_OVER_SAMPLES = 1 << 16
_IN_FLIGHT = 4


@dataclass(frozen=True)
class StaticRecord:
    """The six channels of a static stretch as counts per sample and the scales that make them deg/h and ug.

    `blocks()` gives the record as (n, 6) deg/h and ug blocks in order, what `bench.noise.result.analyse_blocks`
    consumes; `data` the whole (n, 6) array at once."""

    gyro_counts: np.ndarray   # (n, 3) counts per sample
    acc_counts: np.ndarray    # (n, 3)
    gyro_scale: np.ndarray    # counts/s per rad/s
    acc_scale: np.ndarray     # counts/s per m/s^2
    rate_hz: float
    run_id: str
    source: dict
    notes: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.gyro_counts)

    def blocks(self, samples: int = BLOCK_SAMPLES) -> Iterator[np.ndarray]:
        for lo in range(0, len(self), samples):
            sel = slice(lo, lo + samples)
            yield counts_to_allan_units(self.gyro_counts[sel] * self.rate_hz, self.acc_counts[sel] * self.rate_hz,
                                        self.gyro_scale, self.acc_scale)

    @property
    def data(self) -> np.ndarray:
        """(n, 6) deg/h and ug."""
        return counts_to_allan_units(self.gyro_counts * self.rate_hz, self.acc_counts * self.rate_hz,
                                     self.gyro_scale, self.acc_scale)


def _longest_run(counter: np.ndarray) -> tuple[int, int]:
    """[start, stop) of the longest stretch of consecutive counters."""
    if len(counter) == 0:
        return 0, 0
    breaks = np.flatnonzero(np.diff(counter) != 1) + 1
    edges = np.concatenate([[0], breaks, [len(counter)]])
    k = int(np.argmax(np.diff(edges)))
    return int(edges[k]), int(edges[k + 1])


@dataclass(frozen=True)
class _Dwell:
    """What is known of a log before its samples are read: the dwell's counter window, the scales, the notes."""

    log: RunLog
    layout: ImuLayout
    rate_hz: float
    first: int
    last: int
    unit: str
    gyro_scale: np.ndarray
    acc_scale: np.ndarray
    scales_from: str
    notes: list

    def source(self, still_open: bool) -> tuple[dict, str]:
        """(the result's `source`, the run id); the damage is the log's as far as read (read it all first)."""
        log = self.log
        run_id, renamed = run_id_of(log.path, log.metadata)
        if renamed:
            self.notes.append(renamed)
        return ({"kind": "log", "log": Path(log.path).name, "run_id": run_id, "dwell": self.unit,
                 "scales": self.scales_from,
                 "damage": [d.describe() for d in log.scan().lost
                            if not (still_open and d.kind == "no_summary")]}, run_id)

    def missing_note(self, present: int, start: int, stop: int) -> None:
        expected = self.last - self.first + 1
        if stop - start < expected:
            self.notes.append(f"{self.unit}: {expected - present} of its {expected} samples missing; the longest "
                              f"gap-free stretch, {stop - start} samples, is analysed")
        if stop - start < MIN_SAMPLES:
            raise NoiseInputError(f"{self.log.path}: the dwell {self.unit} holds {stop - start} consecutive samples, "
                                  f"too few for the noise analysis (at least {MIN_SAMPLES}, "
                                  f"{MIN_SAMPLES / self.rate_hz:.3g} s at {self.rate_hz:g} Hz)")


def _dwell(path: str | Path, calibration: ImuCoefficients | None, calibration_label: str) -> _Dwell:
    log = read_log(str(path))
    setup = layout_and_config_from_log(log)
    dwells = [(finished.window.first, finished.window.last, unit)
              for unit, (_, finished) in finished_observation_steps(log.events).items()
              if finished.window is not None and isinstance(finished.record, DwellRecord)]
    if not dwells:
        raise NoiseInputError(f"{log.path}: no finished dwell in the log (record one with a static-noise plan)")
    first, last, unit = max(dwells, key=lambda d: d[1] - d[0])
    if calibration is not None:
        scales, scales_from = calibration, calibration_label or "the calibration result"
    elif log.metadata.get("run", {}).get("mode") == "simulator" and setup.config is not None:
        scales, scales_from = setup.config.sim.imu, "the simulated IMU's true scale factors"
    else:
        raise NoiseInputError(f"{log.path}: a hardware log needs the scale factors of a calibration "
                              "(--calibration RESULT.json) to turn counts into deg/h and ug")
    return _Dwell(log, setup.layout, float(setup.rate_hz), int(first), int(last), unit,
                  np.asarray(scales.gyro_scale, dtype=float), np.asarray(scales.acc_scale, dtype=float), scales_from,
                  list(setup.notes))


def static_record(path: str | Path, *, calibration: ImuCoefficients | None = None,
                  calibration_label: str = "", still_open: bool = False) -> StaticRecord:
    """The longest finished dwell of a log as (n, 6) input units, decoded whole (LogError, NoiseInputError).
    `analyse_log` streams instead; this is the reference it is tested against.

    `still_open`: the live run's own log, read before it is closed (its missing summary is not damage)."""
    dwell = _dwell(path, calibration, calibration_label)
    block, _stats = dwell.log.imu_samples(dwell.layout, dwell.rate_hz)
    lo, hi = np.searchsorted(block.counter, [dwell.first, dwell.last + 1])
    start, stop = _longest_run(block.counter[lo:hi])
    dwell.missing_note(int(hi - lo), start, stop)
    sel = slice(lo + start, lo + stop)
    source, run_id = dwell.source(still_open)
    return StaticRecord(block.gyro_counts[sel], block.acc_counts[sel], dwell.gyro_scale, dwell.acc_scale,
                        dwell.rate_hz, run_id, source, tuple(dwell.notes))


class _DwellPhase:
    """The dwell's samples, handed in counter order, into a phase accumulator; the gap-free stretches noted.

    The phase is kept from the first sample of the window on, gaps simply closed up (the sums of a stretch
    use differences of the phase within it). The mean taken off is that of the first `BLOCK_SAMPLES` samples,
    as `StaticRecord.blocks()` into `analyse_blocks` takes it: a log without gaps gives the same phase, bit for
    bit, as the whole-log route."""

    def __init__(self, dwell: _Dwell):
        self.dwell = dwell
        units = np.concatenate([dwell.gyro_scale * DEG_PER_HOUR, dwell.acc_scale * MICRO_G])
        self._factors = np.vstack([np.full(len(CHANNELS), dwell.rate_hz), units])
        self.acc: PhaseAccumulator | None = None
        self._batch: list[tuple[np.ndarray, np.ndarray]] = []   # (gyro, acc) counts not handed on yet
        self._batch_n = 0
        self.present = 0                         # samples of the window handed in
        self.runs: list[list[int]] = []          # [start, stop) of each gap-free stretch, in samples handed in
        self._last_counter: int | None = None

    def add_all(self, blocks: list[ImuSampleBlock]) -> None:
        for block in blocks:
            self.add(block)

    def add(self, block: ImuSampleBlock) -> None:
        d = self.dwell
        lo, hi = (int(i) for i in np.searchsorted(block.counter, [d.first, d.last + 1]))
        if hi <= lo:
            return
        counter = block.counter[lo:hi]
        breaks = (np.flatnonzero(np.diff(counter) != 1) + 1).tolist()
        if self._last_counter is not None and int(counter[0]) == self._last_counter + 1:
            self.runs[-1][1] = self.present + (breaks[0] if breaks else hi - lo)
        else:
            self.runs.append([self.present, self.present + (breaks[0] if breaks else hi - lo)])
        for k, b in enumerate(breaks):
            self.runs.append([self.present + b, self.present + (breaks[k + 1] if k + 1 < len(breaks) else hi - lo)])
        self._last_counter = int(counter[-1])
        self.present += hi - lo
        # the decoder's blocks are a chunk's samples (a few thousand): batched, the per-call costs vanish
        self._batch.append((block.gyro_counts[lo:hi], block.acc_counts[lo:hi]))
        self._batch_n += hi - lo
        if self._batch_n >= BLOCK_SAMPLES:
            self._hand_on()

    def _hand_on(self) -> None:
        """The batched samples in deg/h and ug into the accumulator (made with the first batch's mean)."""
        if not self._batch:
            return
        d = self.dwell
        batch, self._batch, self._batch_n = self._batch, [], 0
        if self.acc is None:   # the first batch as the whole-log route has it, for the same mean
            gyro, acc = (np.concatenate([b[i] for b in batch]) for i in (0, 1))
            data = counts_to_allan_units(gyro * d.rate_hz, acc * d.rate_hz, d.gyro_scale, d.acc_scale)
            self.acc = PhaseAccumulator(d.rate_hz, len(CHANNELS), offset=data[:BLOCK_SAMPLES].mean(axis=0),
                                        capacity=d.last - d.first + 1, threads=1)
            self.acc.add(data)
            return
        # the others a channel at a time, counts x rate / (scale x unit) straight into the phase: the same
        # operations as `counts_to_allan_units` and `add`, so the same bits, without the (n, 6) block
        columns = [np.concatenate([b[i][:, k] for b in batch]) for i in (0, 1) for k in range(3)]
        self.acc.add_scaled(columns, self._factors)

    def finish(self) -> PhaseAccumulator:
        """The accumulator of the longest gap-free stretch (NoiseInputError when it is too short)."""
        self._hand_on()
        start, stop = max(self.runs, key=lambda r: r[1] - r[0]) if self.runs else (0, 0)
        self.dwell.missing_note(self.present, start, stop)
        assert self.acc is not None
        return self.acc if (start, stop) == (0, self.acc.n_samples) else self.acc.stretch(start, stop)


def analyse_log(path: str | Path, *, calibration: ImuCoefficients | None = None, calibration_label: str = "",
                points_per_octave: int = 1, threads: int = 2, still_open: bool = False) -> tuple[NoiseResult, str]:
    """(the noise result of a log's longest dwell, the run id to name its outputs by).

    The frames are decoded chunk by chunk straight into the Allan phase: what is held is the phase (8 bytes per
    sample and channel of the dwell) and a few chunks, never the decoded samples of the whole log."""
    dwell = _dwell(path, calibration, calibration_label)
    phase = _DwellPhase(dwell)
    # the frames are decoded on this thread while another turns the samples into the phase (numpy and zstd
    # let go of the GIL: on two cores the two overlap); at most `_IN_FLIGHT` batches wait between them
    with ThreadPoolExecutor(1, thread_name_prefix="allan-phase") as worker:
        waiting: deque[Future] = deque()
        batch: list[ImuSampleBlock] = []
        batch_n = 0
        for block in dwell.log.imu_sample_blocks(dwell.layout, dwell.rate_hz):
            batch.append(block)
            batch_n += len(block)
            if batch_n >= _HAND_OVER_SAMPLES:
                waiting.append(worker.submit(phase.add_all, batch))
                batch, batch_n = [], 0
                while len(waiting) > _IN_FLIGHT:
                    waiting.popleft().result()
        waiting.append(worker.submit(phase.add_all, batch))
        while waiting:
            waiting.popleft().result()
    acc = phase.finish()
    channels = analyse_phase(acc, points_per_octave=points_per_octave, threads=threads)
    source, run_id = dwell.source(still_open)
    result = NoiseResult.from_channels(channels, dwell.rate_hz, acc.n_samples, points_per_octave=points_per_octave,
                                       source=source, notes=list(dwell.notes))
    return result, run_id


__all__ = ["BLOCK_SAMPLES", "MIN_SAMPLES", "LogError", "NoiseInputError", "StaticRecord", "analyse_log",
           "static_record"]
