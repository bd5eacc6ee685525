"""The extended model's coefficients in a solve and their significance (`bench.solve.extended` computes them)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from bench.model.extended import FAMILIES

#: per family, the level of the significance test (8 families at 0.5 % each: about 4 % of noise-only draws
#: add one)
ALPHA = 0.005


@dataclass
class FamilyTest:
    """The significance of one family: Wald chi-square over its coefficients."""

    term: str
    statistic: float
    dof: int
    p_value: float

    def significant(self, alpha: float = ALPHA) -> bool:
        return self.p_value < alpha

    def to_json(self) -> dict[str, Any]:
        return {"term": self.term, "statistic": _f(self.statistic), "dof": self.dof, "p_value": _f(self.p_value),
                "significant": self.significant()}


@dataclass
class ExtendedFit:
    """The higher-order coefficients of a solve (display units) with their budgets and significance."""

    terms: tuple[str, ...]
    values: dict[str, float] = field(default_factory=dict)
    components: dict[str, dict[str, float]] = field(default_factory=dict)
    tests: dict[str, FamilyTest] = field(default_factory=dict)
    #: the 30 coefficients' noise component under the extended fit (display units)
    noise_30: dict[str, float] = field(default_factory=dict)
    #: family -> why it is not in the model (auto: not significant; not observed by the plan)
    left_out: dict[str, str] = field(default_factory=dict)
    auto: bool = False

    def sigma(self, name: str) -> float:
        parts = self.components.get(name, {})
        return math.sqrt(sum(v * v for v in parts.values())) if parts else math.nan

    def significance_json(self, k: float) -> dict[str, Any]:
        """The significance table: per coefficient value, sigma, U and t; per family its test."""
        rows = []
        for term in self.terms:
            family = FAMILIES[term]
            for name in family.names:
                sigma = self.sigma(name)
                rows.append({"name": name, "family": term, "value": self.values[name], "sigma": _f(sigma),
                             "expanded": _f(k * sigma), "unit": family.result_unit,
                             "t": _f(self.values[name] / sigma if sigma > 0 else math.nan)})
        return {"terms": list(self.terms), "auto": self.auto, "alpha": ALPHA, "coefficients": rows,
                "families": [t.to_json() for t in self.tests.values()], "left_out": dict(self.left_out)}


def _f(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


__all__ = ["ALPHA", "ExtendedFit", "FamilyTest"]
