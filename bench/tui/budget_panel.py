"""The Budget tab: each coefficient's uncertainty budget (README "Uncertainty budget").

Per coefficient sigma (the combined standard uncertainty), U = k sigma and its two
largest components with their shares of sigma^2; above the table the budget's flags
(where the turntable's part came from or that it is NOT included, fits whose residuals
the budget does not explain); below it the highlighted coefficient's whole budget.
"""

from __future__ import annotations

import math
from typing import Any

from rich.text import Text
from textual.app import ComposeResult
from textual.containers import Vertical
from textual.widgets import DataTable, Label

from bench.report.facts import BUDGET_COLUMNS, budget_flags

#: component -> short name (the reports' column titles without their type); short name -> title with its type
BUDGET_SHORT = {key: title.split(" (")[0] for key, title in BUDGET_COLUMNS}
#: the table's names where the reports' are too long for it: at 100 columns the table has 60, and two parts of
#: 16 characters ("bias instab. 93%") cut the last one ("bias instab. 1"); the line under it has the full names
TABLE_SHORT = {"bias instab.": "bias inst.", "unexplained": "scatter"}
_TITLES = {title.split(" (")[0]: title for _, title in BUDGET_COLUMNS}
#: a unit of several IMUs without a result (its Results tab says why)
NO_UNIT_BUDGET = "no uncertainty budget: this unit has no result (the Results tab says why)"
NO_BUDGET = "no uncertainty budget: the result has none (written before result version 2) or no run was solved yet"


def budget_shares(budget: dict[str, float] | None) -> list[tuple[str, float, float]]:
    """(short component name, its standard uncertainty, its share of sigma^2 in %), largest first."""
    parts = {k: v for k, v in (budget or {}).items() if v is not None and math.isfinite(v) and v > 0}
    total = sum(v * v for v in parts.values())
    if not total > 0:
        return []
    return sorted(((BUDGET_SHORT.get(k, k), v, 100.0 * v * v / total) for k, v in parts.items()), key=lambda p: -p[1])


def describe_budget(name: str, coefficient) -> str:
    """'Kg_x: sigma 0.115 = turntable (B) 0.11 (88%) + noise (A) 0.036 (10%) (root-sum-square); U 0.231 (k = 2)'."""
    parts = budget_shares(coefficient.budget)
    what = " + ".join(f"{_TITLES.get(short, short)} {v:.2g} ({share:.0f}%)" for short, v, share in parts)
    k = coefficient.k if coefficient.k is not None else 2.0
    return (f"{name}: sigma {coefficient.sigma:.3g} = {what or 'no components'} (root-sum-square); "
            f"U {coefficient.expanded:.3g} (k = {k:g})")


class BudgetPanel(Vertical):
    """The uncertainty budget of the shown result; `plain` keeps what it drew (tests read it)."""

    DEFAULT_CSS = """
    BudgetPanel { height: 1fr; }
    BudgetPanel #budget-flags { height: auto; width: 1fr; }
    BudgetPanel #budget-unit { height: auto; width: 1fr; }
    BudgetPanel #budget-detail { height: auto; width: 1fr; }
    BudgetPanel DataTable { height: 1fr; }
    """

    def __init__(self, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.result: Any = None
        self.plain = NO_BUDGET
        self.detail = ""            # the highlighted coefficient's whole budget, as shown
        self._names: list[str] = []
        self._lines: list[str] = []
        self.heading = ""           # a run of several IMUs: whose budget this is, and every unit's verdict

    def compose(self) -> ComposeResult:
        unit = Label("", id="budget-unit")
        unit.display = False
        yield unit
        yield Label(NO_BUDGET, id="budget-flags")
        yield DataTable(id="budget-table", zebra_stripes=True, cursor_type="row")
        yield Label("", id="budget-detail")

    def show_result(self, result: Any, heading: str = "") -> None:
        """Show `result`'s budget (None: none); `heading` above it (a run of several IMUs: the unit and every unit's
        verdict)."""
        if result is self.result and heading == self.heading:
            return
        self.result, self.heading = result, heading
        unit = self.query_one("#budget-unit", Label)
        unit.update(heading)
        unit.display = bool(heading)
        table = self.query_one("#budget-table", DataTable)
        table.clear(columns=True)
        coefficients = {} if result is None else {n: c for n, c in result.coefficients.items() if c.budget is not None}
        self._names = list(coefficients)
        if not coefficients:
            none = NO_UNIT_BUDGET if heading and result is None else NO_BUDGET
            self._lines = [none]
            self.query_one("#budget-flags", Label).update(none)
            self.show_detail(-1)
            return
        flags = budget_flags(result)
        warned = any(f.startswith(("WARNING", "UNEXPLAINED")) for f in flags)
        self.query_one("#budget-flags", Label).update(Text("\n".join(flags), style="bold" if warned else ""))
        table.add_columns("name", "sigma", "U", "largest part", "next")
        lines = list(flags)
        for name, c in coefficients.items():
            parts = [f"{TABLE_SHORT.get(short, short)} {share:.0f}%" for short, _, share in budget_shares(c.budget)[:2]]
            row = [name, _num(c.sigma), _num(c.expanded), *parts, *["-"] * (2 - len(parts))]
            table.add_row(*row)
            lines.append(" ".join(row))
        self._lines = lines
        self.show_detail(0)

    def show_detail(self, row: int) -> None:
        """The whole budget of the coefficient on table row `row` (none: -1) under the table."""
        name = self._names[row] if 0 <= row < len(self._names) else None
        self.detail = "" if name is None or self.result is None else describe_budget(name,
                                                                                      self.result.coefficients[name])
        self.query_one("#budget-detail", Label).update(self.detail)
        self.plain = "\n".join(([self.heading] if self.heading else []) + self._lines
                               + ([self.detail] if self.detail else []))

    def on_data_table_row_highlighted(self, event: DataTable.RowHighlighted) -> None:
        self.show_detail(event.cursor_row)


def _num(x: float | None) -> str:
    return f"{x:.3g}" if x is not None and math.isfinite(x) else "-"


__all__ = ["BUDGET_SHORT", "BudgetPanel", "budget_shares", "describe_budget"]
