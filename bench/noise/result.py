"""The noise result file (`*.noise.json`, versioned) and the per-channel analysis that fills it.

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
from typing import Any

import numpy as np

from bench.errors import InputError
from bench.files import MAX_INPUT_FILE_BYTES, InputFileError, parse_json, read_input_bytes, write_output_text
from bench.model.units import MICRO_G
from bench.noise.allan import AllanCurve, AllanError, PhaseAccumulator, allan_curves
from bench.noise.fit import MIN_RECORD_SAMPLES, ChannelFit, TermFit, fit_curve

FORMAT = "turntable-bench/noise"
VERSION = 1
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "acc_x", "acc_y", "acc_z")
#: result term name -> (fit attribute, factor from the fit's coefficient, unit), per sensor kind
GYRO_TERMS = {"arw": ("random_walk", 1.0 / 60.0, "deg/sqrt(h)"),
              "bias_instability": ("bias_instability", 1.0, "deg/h"),
              "rrw": ("rate_random_walk", 60.0, "deg/h/sqrt(h)"),
              "quantisation": ("quantisation", 1.0, "arcsec")}
ACC_TERMS = {"vrw": ("random_walk", 1.0, "ug/sqrt(Hz)"),
             "bias_instability": ("bias_instability", 1.0, "ug"),
             "rrw": ("rate_random_walk", 60.0, "ug/sqrt(h)"),
             "quantisation": ("quantisation", 1.0, "ug s")}


class NoiseResultError(InputError):
    """A noise result file that cannot be used (not JSON, another format or version, fields missing)."""


@dataclass(frozen=True)
class ChannelNoise:
    """One channel's Allan curve and fitted terms in display units."""

    name: str
    unit: str
    curve: AllanCurve
    fit: ChannelFit
    terms: dict[str, dict[str, Any]]
    not_resolved: dict[str, str] = field(default_factory=dict)   # result term name -> why it is not given

    def to_json(self) -> dict:
        c = self.curve
        out = {"unit": self.unit, "tau_s": c.tau_s.tolist(), "adev": c.adev.tolist(),
               "adev_low": c.adev_low.tolist(), "adev_high": c.adev_high.tolist(), "edf": c.edf.tolist(),
               "terms": self.terms}
        if self.not_resolved:
            out["terms_not_resolved"] = self.not_resolved
        if self.fit.model is not None:
            out["model"] = self.fit.model
        return out


def _term_json(fit: TermFit, factor: float, unit: str) -> dict[str, Any]:
    out: dict[str, Any] = {"value": fit.value * factor, "sigma": fit.sigma * factor, "unit": unit,
                           "region_tau_s": list(fit.tau_s), "points": list(fit.points)}
    if fit.upper_bound:
        out["upper_bound"] = True
    return out


#: What an upper bound means, per term (in the term's JSON as "upper_bound_means").
UPPER_BOUND_MEANS = {
    "random_walk": "not resolved: the white noise is hidden (under quantisation and a bias) over the fitted taus; "
                   "value is a 2-sigma upper bound",
    "rate_random_walk": "not resolved: the record cannot tell it from zero (below 2 sigma); value is a 2-sigma upper "
                        "bound",
    "bias_instability": "the fitted curve still falls at the longest tau: the floor may be lower than this minimum "
                        "over the record's taus"}


def check_record_length(n_samples: int, rate_hz: float, what: str = "the record") -> None:
    """AllanError when `n_samples` are too few for the noise analysis (`MIN_RECORD_SAMPLES`), naming the minimum."""
    if n_samples < MIN_RECORD_SAMPLES:
        raise AllanError(f"{what} holds {n_samples} samples ({n_samples / rate_hz:.3g} s at {rate_hz:g} Hz): the noise "
                         f"analysis needs at least {MIN_RECORD_SAMPLES} ({MIN_RECORD_SAMPLES / rate_hz:.3g} s at this "
                         "rate; its model's five terms need six Allan points from the white-noise start)")


def channel_noise(name: str, curve: AllanCurve) -> ChannelNoise:
    """Fit one channel's curve and express its terms in display units; a term the record does not resolve is in
    the channel's `terms_not_resolved` with the reason, not in `terms`."""
    fit = fit_curve(curve)
    gyro = name.startswith("gyro")
    terms: dict[str, dict[str, Any]] = {}
    not_resolved: dict[str, str] = {}
    for key, (attr, factor, unit) in (GYRO_TERMS if gyro else ACC_TERMS).items():
        found = getattr(fit, attr)
        if found is not None:
            terms[key] = _term_json(found, factor, unit)
            if found.upper_bound:
                terms[key]["upper_bound_means"] = UPPER_BOUND_MEANS[attr]
        elif attr in fit.not_resolved:
            not_resolved[key] = fit.not_resolved[attr]
    if not gyro and "vrw" in terms:
        terms["vrw"]["mps_rt_h"] = terms["vrw"]["value"] * MICRO_G * 60.0
    return ChannelNoise(name, "deg/h" if gyro else "ug", curve, fit, terms, not_resolved)


def analyse(data: np.ndarray, rate_hz: float, *, points_per_octave: int = 1, threads: int = 2) -> list[ChannelNoise]:
    """The six channels of `data` (n, 6): gyros x, y, z in deg/h, accelerometers x, y, z in ug (AllanError when
    the record is too short: `check_record_length`)."""
    check_record_length(len(data), rate_hz)
    curves = allan_curves(data, rate_hz, points_per_octave=points_per_octave, threads=threads)
    return [channel_noise(name, curve) for name, curve in zip(CHANNELS, curves)]


def analyse_blocks(blocks: Iterable[np.ndarray], rate_hz: float, *, capacity: int = 0, points_per_octave: int = 1,
                   threads: int = 2) -> list[ChannelNoise]:
    """`analyse` of a record handed as (n_i, 6) blocks in order (a streaming reader's): only the phase is kept,
    8 bytes per sample and channel (`capacity`: the samples expected, to allocate it once)."""
    acc = PhaseAccumulator(rate_hz, len(CHANNELS), capacity=capacity)
    for block in blocks:
        acc.add(block)
    return analyse_phase(acc, points_per_octave=points_per_octave, threads=threads)


def analyse_phase(acc: PhaseAccumulator, *, points_per_octave: int = 1, threads: int = 2) -> list[ChannelNoise]:
    """`analyse` of the six channels an accumulator holds."""
    check_record_length(acc.n_samples, acc.rate_hz)
    curves = acc.curves(points_per_octave=points_per_octave, threads=threads)
    return [channel_noise(name, curve) for name, curve in zip(CHANNELS, curves)]


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
    def from_channels(cls, channels: list[ChannelNoise], rate_hz: float, n_samples: int, **kwargs) -> "NoiseResult":
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


__all__ = ["ACC_TERMS", "CHANNELS", "FORMAT", "GYRO_TERMS", "VERSION", "ChannelNoise", "NoiseResult",
           "NoiseResultError", "analyse", "analyse_blocks", "analyse_phase", "channel_noise", "check_record_length"]
