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
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.errors import InputError
from bench.log.names import run_id_of
from bench.log.reader import LogError, read_log
from bench.log.run_info import layout_and_config_from_log
from bench.model.imu import ImuCoefficients
from bench.noise.result import NoiseResult, analyse_blocks
from bench.noise.simulate import counts_to_allan_units
from bench.solve.extract import finished_observation_steps

#: A dwell shorter than this many samples has no Allan deviation worth the name.
MIN_SAMPLES = 64


class NoiseInputError(InputError):
    """A log the noise characterisation cannot use (no dwell, too short, no scale factors)."""


#: Samples per block handed to the Allan accumulator (6 channels x 8 bytes: 12 MB of float64 at a time).
BLOCK_SAMPLES = 1 << 18


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


def static_record(path: str | Path, *, calibration: ImuCoefficients | None = None,
                  calibration_label: str = "", still_open: bool = False) -> StaticRecord:
    """The longest finished dwell of a log as (n, 6) input units (LogError, NoiseInputError).

    `still_open`: the live run's own log, read before it is closed (its missing summary is not damage)."""
    log = read_log(str(path))
    setup = layout_and_config_from_log(log)
    notes = list(setup.notes)
    dwells = [(finished.data["counter_first"], finished.data["counter_last"], unit)
              for unit, (_, finished) in finished_observation_steps(log.events).items()
              if finished.data["step"].get("kind") == "dwell"]
    if not dwells:
        raise NoiseInputError(f"{log.path}: no finished dwell in the log (record one with a static-noise plan)")
    first, last, unit = max(dwells, key=lambda d: d[1] - d[0])
    block, _stats = log.imu_samples(setup.layout, setup.rate_hz)
    lo, hi = np.searchsorted(block.counter, [first, last + 1])
    start, stop = _longest_run(block.counter[lo:hi])
    expected = last - first + 1
    if stop - start < expected:
        notes.append(f"{unit}: {expected - (hi - lo)} of its {expected} samples missing; the longest gap-free "
                     f"stretch, {stop - start} samples, is analysed")
    if stop - start < MIN_SAMPLES:
        raise NoiseInputError(f"{log.path}: the dwell {unit} holds {stop - start} consecutive samples, too few for an "
                              f"Allan deviation (at least {MIN_SAMPLES})")
    if calibration is not None:
        scales, scales_from = calibration, calibration_label or "the calibration result"
    elif log.metadata.get("run", {}).get("mode") == "simulator" and setup.config is not None:
        scales, scales_from = setup.config.sim.imu, "the simulated IMU's true scale factors"
    else:
        raise NoiseInputError(f"{log.path}: a hardware log needs the scale factors of a calibration "
                              "(--calibration RESULT.json) to turn counts into deg/h and ug")
    sel = slice(lo + start, lo + stop)
    rate_hz = float(setup.rate_hz)
    run_id, renamed = run_id_of(log.path, log.metadata)
    if renamed:
        notes.append(renamed)
    source = {"kind": "log", "log": Path(log.path).name, "run_id": run_id, "dwell": unit, "scales": scales_from,
              "damage": [d.describe() for d in log.lost if not (still_open and d.kind == "no_summary")]}
    return StaticRecord(block.gyro_counts[sel], block.acc_counts[sel], np.asarray(scales.gyro_scale, dtype=float),
                        np.asarray(scales.acc_scale, dtype=float), rate_hz, run_id, source, tuple(notes))


def analyse_log(path: str | Path, *, calibration: ImuCoefficients | None = None, calibration_label: str = "",
                points_per_octave: int = 1, threads: int = 2, still_open: bool = False) -> tuple[NoiseResult, str]:
    """(the noise result of a log's longest dwell, the run id to name its outputs by)."""
    record = static_record(path, calibration=calibration, calibration_label=calibration_label,
                           still_open=still_open)
    channels = analyse_blocks(record.blocks(), record.rate_hz, capacity=len(record),
                              points_per_octave=points_per_octave, threads=threads)
    result = NoiseResult.from_channels(channels, record.rate_hz, len(record), points_per_octave=points_per_octave,
                                       source=record.source, notes=list(record.notes))
    return result, record.run_id


__all__ = ["BLOCK_SAMPLES", "MIN_SAMPLES", "LogError", "NoiseInputError", "StaticRecord", "analyse_log",
           "static_record"]
