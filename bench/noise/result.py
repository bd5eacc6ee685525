"""The per-channel noise analysis that fills a noise result file (`bench.model.noise_result`): each channel's
Allan curve fitted and its terms expressed in the file's display units."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from bench.model.noise_result import CHANNELS
from bench.model.units import MICRO_G
from bench.noise.allan import AllanCurve, AllanError, PhaseAccumulator, allan_curves
from bench.noise.fit import MIN_RECORD_SAMPLES, ChannelFit, TermFit, fit_curve

#: result term name -> (fit attribute, factor from the fit's coefficient, unit), per sensor kind
GYRO_TERMS = {"arw": ("random_walk", 1.0 / 60.0, "deg/sqrt(h)"),
              "bias_instability": ("bias_instability", 1.0, "deg/h"),
              "rrw": ("rate_random_walk", 60.0, "deg/h/sqrt(h)"),
              "quantisation": ("quantisation", 1.0, "arcsec")}
ACC_TERMS = {"vrw": ("random_walk", 1.0, "ug/sqrt(Hz)"),
             "bias_instability": ("bias_instability", 1.0, "ug"),
             "rrw": ("rate_random_walk", 60.0, "ug/sqrt(h)"),
             "quantisation": ("quantisation", 1.0, "ug s")}


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


__all__ = ["ACC_TERMS", "GYRO_TERMS", "ChannelNoise", "analyse", "analyse_blocks", "analyse_phase", "channel_noise",
           "check_record_length"]
