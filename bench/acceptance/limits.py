"""The acceptance limits of the configuration's `[acceptance]` section (parsed by `bench.config.acceptance`).

Per coefficient family (`[acceptance.Kg]`) or per coefficient (`[acceptance.Kg_x]`, which
overrides its family key by key), in the result's units (`bench.model.families`):
`min` and `max` (allowed range of the value, both or neither), `max_sigma` (largest 1-sigma), `max_change`
(largest |value - reference|, the reference being `nominal` when given, else the same
coefficient in `[acceptance] reference`, the IMU's previous or nominal result file).
Run-wide: `max_lost_samples` (IMU samples lost on the link), `max_residual_sigma` (largest
|residual| / sigma of a position or rotation). `[acceptance.verification]`: the largest
|error| after compensation on the verification plan, per quantity (`VERIFICATION_LIMITS`), and
`beyond_uncertainty`: an error beyond its expanded uncertainty U fails the verdict ("fail", the
default) or is only marked ("warn").
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

#: `[acceptance.verification]` key -> (unit, upper bound of the limit)
VERIFICATION_LIMITS = {"gyro_bias_dph": ("deg/h", 3600.0), "gyro_scale_ppm": ("ppm", 1e6),
                       "gyro_misalignment_arcsec": ("arcsec", 3600.0), "acc_bias_ug": ("ug", 1e6),
                       "acc_scale_ppm": ("ppm", 1e6), "acc_misalignment_arcsec": ("arcsec", 3600.0),
                       # an extended result's gyro families (bench.verify.errors)
                       "gyro_g_sensitivity_dph_per_g": ("deg/h per g", 3600.0), "gyro_asymmetry_ppm": ("ppm", 1e6),
                       "gyro_nonlinearity_ppm_per_dps": ("ppm per deg/s", 1e4)}
#: `[acceptance.verification] beyond_uncertainty`: an error beyond its U fails, or is only marked
BEYOND_FAIL, BEYOND_WARN = "fail", "warn"
#: the keys of one family's or coefficient's limits, in the order checks are listed
COEFFICIENT_KEYS = ("min", "max", "max_sigma", "max_change", "nominal")


@dataclass(frozen=True)
class CoefficientLimits:
    """Limits on one coefficient (or a family's default for its coefficients); None = no limit."""

    min: float | None = None
    max: float | None = None
    max_sigma: float | None = None
    max_change: float | None = None
    nominal: float | None = None

    def over(self, base: "CoefficientLimits") -> "CoefficientLimits":
        """These limits with `base`'s where these have none (a coefficient's over its family's)."""
        return CoefficientLimits(**{f.name: getattr(self, f.name) if getattr(self, f.name) is not None
                                    else getattr(base, f.name) for f in fields(self)})

    @property
    def empty(self) -> bool:
        return all(getattr(self, f.name) is None for f in fields(self))


@dataclass(frozen=True)
class AcceptanceLimits:
    """Everything `[acceptance]` sets; an empty one checks nothing beyond the run's quality checks."""

    families: dict[str, CoefficientLimits] = field(default_factory=dict)       # "Kg" -> limits
    coefficients: dict[str, CoefficientLimits] = field(default_factory=dict)   # "Kg_x" -> limits
    max_lost_samples: int | None = None
    max_residual_sigma: float | None = None
    #: canonical name -> value (result units) of the reference result, when `reference` is set
    reference: dict[str, float] = field(default_factory=dict)
    reference_name: str = ""
    reference_path: str = ""      # the file, attached to the run log (a re-solve elsewhere finds it there)
    #: `[acceptance.verification]`: verification quantity (`gyro_bias_dph`, ...) -> largest |error|
    verification: dict[str, float] = field(default_factory=dict)
    verification_beyond_uncertainty: str = BEYOND_FAIL

    def for_coefficient(self, name: str, family: str) -> CoefficientLimits:
        own = self.coefficients.get(name, CoefficientLimits())
        return own.over(self.families.get(family, CoefficientLimits()))


__all__ = ["BEYOND_FAIL", "BEYOND_WARN", "COEFFICIENT_KEYS", "VERIFICATION_LIMITS", "AcceptanceLimits",
           "CoefficientLimits"]
