"""The noise result file (`*.noise.json`, versioned): what `bench noise` and a static-noise run write and
`[imu] noise = FILE` reads (the analysis that fills it is `bench.noise.result`).

    {"format": "turntable-bench/noise", "version": 1,
     "source": {...}, "rate_hz": 200.0, "n_samples": N, "duration_s": T, "points_per_octave": 1,
     "channels": {"gyro_x": {"unit": "deg/h", "tau_s": [...], "adev": [...], "adev_low": [...],
                             "adev_high": [...], "edf": [...], "terms_not_resolved": {"quantisation": "why"},
                             "terms": {"arw": {"value", "sigma", "unit", "region_tau_s": [lo, hi],
                                               "points": [...]}, "bias_instability": {..., "upper_bound"},
                                       "rrw": {...}, "quantisation": {...}}}, ...},
     "summary": {"gyro_bias_stability_dph": x, "acc_bias_stability_ug": y},
     "sim_truth": {...}}                                  # simulated data only

Units: gyro ADEV in deg/h, ARW deg/sqrt(h), bias instability deg/h, RRW deg/h/sqrt(h),
quantisation arcsec; accelerometer ADEV in ug, VRW ug/sqrt(Hz) (= ADEV at 1 s; also
given in m/s/sqrt(h)), bias instability ug, RRW ug/sqrt(h), quantisation ug s. The
summary's bias stabilities are the largest of the three axes (what `bench run` feeds
the solve with `[imu] noise = FILE`); a bias instability whose minimum the record
does not reach is an upper bound and says so.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

from bench.errors import InputError
from bench.files import MAX_INPUT_FILE_BYTES, InputFileError, parse_json, read_input_bytes, write_output_text

FORMAT = "turntable-bench/noise"
VERSION = 1
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")


class NoiseResultError(InputError):
    """A noise result file that cannot be used (not JSON, another format or version, fields missing)."""


class NamedChannel(Protocol):
    """One analysed channel as the file holds it (`bench.noise.result.ChannelNoise`)."""

    @property
    def name(self) -> str: ...

    def to_json(self) -> dict: ...


@dataclass
class NoiseResult:
    """A noise characterisation: per channel curve and terms, the summary, where the data came from."""

    channels: dict[str, dict[str, Any]]
    rate_hz: float
    n_samples: int
    points_per_octave: int = 1
    source: dict[str, Any] = field(default_factory=dict)
    sim_truth: dict[str, Any] | None = None
    notes: list[str] = field(default_factory=list)

    @classmethod
    def from_channels(cls, channels: Iterable[NamedChannel], rate_hz: float, n_samples: int,
                      **kwargs) -> "NoiseResult":
        return cls({c.name: c.to_json() for c in channels}, float(rate_hz), int(n_samples), **kwargs)

    @property
    def duration_s(self) -> float:
        return self.n_samples / self.rate_hz

    def _worst(self, prefix: str) -> float | None:
        values = [c["terms"]["bias_instability"]["value"] for name, c in self.channels.items()
                  if name.startswith(prefix) and "bias_instability" in c.get("terms", {})]
        return max(values) if values else None

    @property
    def gyro_bias_stability_dph(self) -> float | None:
        """The largest gyro bias instability (deg/h), None if no gyro has one."""
        return self._worst("gyro")

    @property
    def acc_bias_stability_ug(self) -> float | None:
        """The largest accelerometer bias instability (ug), None if none has one."""
        return self._worst("acc")

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "format": FORMAT, "version": VERSION, "source": self.source, "rate_hz": self.rate_hz,
            "n_samples": self.n_samples, "duration_s": self.duration_s, "points_per_octave": self.points_per_octave,
            "channels": self.channels,
            "summary": {"gyro_bias_stability_dph": self.gyro_bias_stability_dph,
                        "acc_bias_stability_ug": self.acc_bias_stability_ug},
            "notes": self.notes}
        if self.sim_truth is not None:
            out["sim_truth"] = self.sim_truth
        return out

    def save(self, path: str | Path) -> None:
        write_output_text(path, json.dumps(self.to_json(), indent=1, allow_nan=False) + "\n")

    @classmethod
    def from_json(cls, doc: Any, source: str = "<json>") -> "NoiseResult":
        if not isinstance(doc, dict):
            raise NoiseResultError(f"{source}: not a noise result (a JSON object with format {FORMAT!r})")
        if doc.get("format") != FORMAT:
            raise NoiseResultError(f"{source}: format is {str(doc.get('format'))[:60]!r}, expected {FORMAT!r}")
        if doc.get("version") != VERSION:
            raise NoiseResultError(f"{source}: unsupported version {str(doc.get('version'))[:20]} "
                                   f"(supported: {VERSION})")
        channels = doc.get("channels")
        if not isinstance(channels, dict) or not all(isinstance(c, dict) for c in channels.values()):
            raise NoiseResultError(f"{source}: channels must be an object of channel objects")
        for name, channel in channels.items():
            terms = channel.get("terms", {})
            if not isinstance(terms, dict):
                raise NoiseResultError(f"{source}: channels.{str(name)[:40]}.terms must be an object")
            for key, term in terms.items():
                value = term.get("value") if isinstance(term, dict) else None
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    raise NoiseResultError(f"{source}: channels.{str(name)[:40]}.terms.{str(key)[:40]}.value must be "
                                           "a finite number >= 0")
        rate_hz, n_samples = doc.get("rate_hz"), doc.get("n_samples")
        if not isinstance(rate_hz, (int, float)) or isinstance(rate_hz, bool) or not rate_hz > 0 \
                or not math.isfinite(rate_hz):
            raise NoiseResultError(f"{source}: rate_hz must be a positive number")
        if not isinstance(n_samples, int) or isinstance(n_samples, bool) or n_samples < 0:
            raise NoiseResultError(f"{source}: n_samples must be a whole number >= 0")
        return cls(channels, float(rate_hz), n_samples, int(doc.get("points_per_octave", 1) or 1),
                   dict(doc.get("source") or {}), doc.get("sim_truth"), list(doc.get("notes") or []))

    @classmethod
    def load(cls, path: str | Path) -> "NoiseResult":
        """Read a noise result file (OSError if unreadable; NoiseResultError if it is not one)."""
        path = Path(path)
        raw = read_input_bytes(path, max_bytes=MAX_INPUT_FILE_BYTES, what="noise result")
        try:
            doc = parse_json(raw, str(path))
        except InputFileError as exc:
            raise NoiseResultError(str(exc)) from None
        return cls.from_json(doc, str(path))


__all__ = ["CHANNELS", "FORMAT", "VERSION", "NamedChannel", "NoiseResult", "NoiseResultError"]
