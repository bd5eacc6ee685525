"""The extended model's significance table in the reports (`quality.significance`, `bench.solve.extended`)."""

from __future__ import annotations

from dataclasses import dataclass

from bench.model.result import CalibrationResult
from bench.report.compare import fmt

COEFFICIENT_HEADER = ["name", "family", "value", "1-sigma", "U", "unit", "t = value / sigma"]
FAMILY_HEADER = ["family", "Wald chi2", "dof", "p", "significant"]


@dataclass
class SignificanceTable:
    """The rows of the significance table, as text."""

    note: str
    coefficients: list[list[str]]
    families: list[list[str]]
    left_out: list[str]


def significance_table(result: CalibrationResult) -> SignificanceTable | None:
    """The table of a result solved with the extended model, None for the 30-coefficient model."""
    table = result.quality.significance
    if table is None:
        return None
    auto = bool(table.get("auto"))
    alpha = table.get("alpha")
    note = (f"Model: the 30 coefficients and {', '.join(table.get('terms', [])) or 'no higher-order family'}"
            + (f" (chosen by the data: each family kept is significant at p < {fmt(alpha, 3)})" if auto else "")
            + ". t is the value over its 1-sigma; a family's Wald chi-square is the likelihood-ratio test of "
              "adding it.")
    coefficients = [[str(row.get("name")), str(row.get("family")), fmt(row.get("value"), 6), fmt(row.get("sigma"), 3),
                     fmt(row.get("expanded"), 3), str(row.get("unit")), fmt(row.get("t"), 3)]
                    for row in table.get("coefficients", [])]
    families = [[str(row.get("term")), fmt(row.get("statistic"), 4), str(row.get("dof")), fmt(row.get("p_value"), 3),
                 "yes" if row.get("significant") else "no"] for row in table.get("families", [])]
    left_out = [f"{term}: {why}" for term, why in (table.get("left_out") or {}).items()]
    return SignificanceTable(note, coefficients, families, left_out)


__all__ = ["COEFFICIENT_HEADER", "FAMILY_HEADER", "SignificanceTable", "significance_table"]
