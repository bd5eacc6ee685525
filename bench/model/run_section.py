"""The `run` section of a calibration result: which run, recorded how, solved when and with what link quality.

`bench run` writes it when it finishes (`finished_utc`, and `sim` on the simulator);
`bench solve` when it re-solves a log (`recorded_with`, `solved_utc`, `solved_by`, and for a
plain solve `subset`, `started_utc`, `left_out`, `damage`). `RunInfo.to_dict` gives the
section in the order result files have always had it, without the entries a writer does not
set; entries added to the dict later (a thermal block, the verification, the thermal model)
come back from `from_dict` in `extra`, in their order. The quality failures are kept as their lines and come
back with their kinds (`bench.model.quality.from_text`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from typing import Any, Mapping

from bench.model.quality import QualityFailure, from_text, texts

#: The section's entries in the order of the result file (the optional ones only when set).
_ORDER = ("run_id", "mode", "operator", "software_version", "recorded_with", "state", "log", "logs", "positions",
          "rotations", "subset", "started_utc", "finished_utc", "solved_utc", "solved_by", "imu", "site",
          "quality_failures", "sim", "imu_link", "lost_samples", "left_out", "damage", "notes")


def utc_stamp() -> str:
    """Now, as the result files write a time: "2026-11-27T15:03:12Z"."""
    return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())


@dataclass
class RunInfo:
    """A result's `run` section (see the module docstring for who sets the optional entries)."""

    run_id: str
    mode: str                           # "simulator" | "hardware" ("" when a log does not say)
    operator: str
    software_version: str               # of the software that solved
    state: str                          # the run's final state ("done", "aborted", ...)
    log: str                            # the (last) log's file name
    logs: list[str]                     # every log's file name, oldest first
    positions: str                      # schedule names ("" = none)
    rotations: str
    imu: dict[str, str]                 # model, serial
    site: dict[str, Any]
    quality_failures: list[QualityFailure]   # the file keeps their lines
    imu_link: dict[str, Any]            # the IMU link statistics (and the CAN time base, live)
    lost_samples: dict[str, Any]
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
    extra: dict[str, Any] = field(default_factory=dict)   # entries added after the run (in their order)

    def to_dict(self) -> dict[str, Any]:
        out = {name: getattr(self, name) for name in _ORDER if getattr(self, name) is not None}
        out["quality_failures"] = texts(self.quality_failures)
        return out | self.extra

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "RunInfo":
        """The section of a result file (ValueError when a required entry is missing)."""
        required = [f.name for f in fields(cls) if f.name != "extra" and f.default is not None]
        missing = [name for name in required if name not in data]
        if missing:
            raise ValueError(f"the run section lacks {', '.join(missing)}")
        known = {name: data[name] for name in _ORDER if name in data}
        known["quality_failures"] = [from_text(str(text)) for text in data["quality_failures"]]
        return cls(**known, extra={k: v for k, v in data.items() if k not in _ORDER})


__all__ = ["RunInfo", "utc_stamp"]
