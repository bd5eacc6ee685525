"""The `run` section of a calibration result: which run, recorded how, solved when and with what link quality.

`bench run` writes it when it finishes (`started_utc` from its first log, `finished_utc`, and `sim` on the
simulator);
`bench solve` when it re-solves a log (`recorded_with`, `solved_utc`, `solved_by`, and for a
plain solve `subset`, `started_utc`, `left_out`, `damage`). `RunInfo.to_dict` gives the
section in the order result files have always had it, without the entries a writer does not
set; entries added later (a thermal block, the verification, the thermal model) are kept in `extra`, in their
order. The quality failures are kept as their lines and come back with their kinds (`bench.model.quality.from_text`).
The IMU (`ImuIdentity`), its link statistics (`ImuLink`) and the lost samples (`LostSamples`) are sections of
their own (`bench.model.sections`: read from a file, each writes back what it read). The site stays the object
the file has: `Site` writes every entry, and a section's site may have fewer.
"""

from __future__ import annotations

import time
from dataclasses import MISSING, dataclass, fields
from typing import Any, Mapping, Self

from bench.model.quality import QualityFailure, from_text, texts
from bench.model.sections import ResultFormatError, Section, count, flag, list_of, number, obj, text


def utc_stamp() -> str:
    """Now, as the result files write a time: "2026-11-27T15:03:12Z"."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


@dataclass
class ImuIdentity(Section):
    """The `run.imu` entry: which IMU was calibrated (None: an entry the file lacks)."""

    model: str | None
    serial: str | None

    READERS = {"model": text, "serial": text}


#: the IMU link's counters (`drivers.imu.samples.ImuStats`, in its order) and the CAN time base's figures
#: (`drivers.imu.receiver.TimeBase`, live runs only)
LINK_COUNTERS = ("frames", "frames_ok", "crc_errors", "wrong_length", "unknown_id", "late", "duplicates",
                 "out_of_order", "samples", "incomplete_samples", "counter_gaps", "joined_mid_sample",
                 "left_mid_sample")
TIME_BASE = ("can_time_offset_s", "can_lag_min_s", "can_lag_max_s")


@dataclass
class ImuLink(Section):
    """The `run.imu_link` entry: the IMU link's statistics, and on a live run the CAN time base (seconds).
    None: an entry the file lacks (an older file's statistics have fewer counters; a solve has no time base)."""

    frames: int | None = None
    frames_ok: int | None = None
    crc_errors: int | None = None
    wrong_length: int | None = None
    unknown_id: int | None = None
    late: int | None = None
    duplicates: int | None = None
    out_of_order: int | None = None
    samples: int | None = None
    incomplete_samples: int | None = None
    counter_gaps: int | None = None
    joined_mid_sample: int | None = None
    left_mid_sample: int | None = None
    can_time_offset_s: float | None = None
    can_lag_min_s: float | None = None
    can_lag_max_s: float | None = None

    READERS = {**{name: count for name in LINK_COUNTERS}, **{name: number for name in TIME_BASE}}


def _counts(value: Any, where: str) -> dict[str, int]:
    return {str(k): count(v, f"{where}.{k}") for k, v in obj(value, where).items()}


@dataclass
class LostSamples(Section):
    """The `run.lost_samples` entry: the samples the IMU link lost, in all (`total`), per dwell or turn window
    (`in_windows`, unit -> count) and outside every window (`outside_windows`); None: an entry the file lacks."""

    total: int | None = None
    in_windows: dict[str, int] | None = None
    outside_windows: int | None = None

    READERS = {"total": count, "in_windows": _counts, "outside_windows": count}


def _failures(value: Any, where: str) -> list[QualityFailure]:
    return [from_text(line) for line in list_of(text)(value, where)]


@dataclass
class RunInfo(Section):
    """A result's `run` section (see the module docstring for who sets the optional entries).

    The bench's writers give every entry up to `lost_samples`; a result file's section may lack any (an older
    file's, a simulated thermal point's): those are None (`from_dict(..., complete=False)`)."""

    run_id: str | None
    mode: str | None                    # "simulator" | "hardware" ("" when a log does not say)
    operator: str | None
    software_version: str | None        # of the software that solved
    state: str | None                   # the run's final state ("done", "aborted", ...)
    log: str | None                     # the (last) log's file name
    logs: list[str] | None              # every log's file name, oldest first
    positions: str | None               # schedule names ("" = none)
    rotations: str | None
    imu: ImuIdentity | None
    site: dict[str, Any] | None         # `Site.to_dict` (an older file's may have fewer entries)
    quality_failures: list[QualityFailure] | None   # the file keeps their lines
    imu_link: ImuLink | None            # the IMU link statistics (and the CAN time base, live)
    lost_samples: LostSamples | None
    recorded_with: str | None = None    # bench solve: the software version that recorded the log
    subset: bool | None = None          # bench solve: a what-if subset, never the run's record
    started_utc: str | None = None
    finished_utc: str | None = None     # bench run
    solved_utc: str | None = None       # bench solve
    solved_by: str | None = None
    sim: dict[str, Any] | None = None   # bench run on the simulator: its table (`bench.verify.plan.sim_table_record`)
    left_out: list[str] | None = None
    damage: list[str] | None = None
    notes: list[str] | None = None

    READERS = {"run_id": text, "mode": text, "operator": text, "software_version": text, "recorded_with": text,
               "state": text, "log": text, "logs": list_of(text), "positions": text, "rotations": text,
               "subset": flag, "started_utc": text, "finished_utc": text, "solved_utc": text, "solved_by": text,
               "imu": ImuIdentity.from_dict, "site": obj, "quality_failures": _failures, "sim": obj,
               "imu_link": ImuLink.from_dict, "lost_samples": LostSamples.from_dict, "left_out": list_of(text),
               "damage": list_of(text), "notes": list_of(text)}

    def _dumped(self, name: str) -> Any:
        if name == "quality_failures":
            return None if self.quality_failures is None else texts(self.quality_failures)
        return super()._dumped(name)

    def link_dict(self) -> dict[str, Any] | None:
        """The `imu_link` entry as the reports take it (None: the section has none)."""
        return None if self.imu_link is None else self.imu_link.to_dict()

    @classmethod
    def empty(cls) -> "RunInfo":
        """A section with no entry (a result made in code without one)."""
        return cls.from_dict({}, complete=False)

    @classmethod
    def from_dict(cls, data: Any, where: str = "run", *, complete: bool = True) -> Self:
        """The section of a result file: with `complete`, as the bench writes it (ResultFormatError, a ValueError,
        when a required entry is missing); any entry of the wrong type is refused, naming it."""
        if complete and isinstance(data, Mapping):
            missing = [name for name in _REQUIRED if name not in data]
            if missing:
                raise ResultFormatError(f"the run section lacks {', '.join(missing)}")
        return cls(**cls._read(data, where))


#: the entries the bench's writers always give (the fields without a default)
_REQUIRED = tuple(f.name for f in fields(RunInfo) if f.default is MISSING and f.default_factory is MISSING)


__all__ = ["LINK_COUNTERS", "TIME_BASE", "ImuIdentity", "ImuLink", "LostSamples", "RunInfo", "utc_stamp"]
