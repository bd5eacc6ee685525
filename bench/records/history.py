"""A unit's calibration history: each coefficient over time, its changes in sigma, its drift per year.

`unit_history(records, serial)` reads the unit's latest result of every calibration run
(`Records.history_rows`, oldest first) and computes, per coefficient:

- the change between consecutive calibrations in units of their combined 1-sigma,
  z = (v_k - v_{k-1}) / sqrt(s_k^2 + s_{k-1}^2) (None when a sigma is unknown);
- the drift per year: the slope of a straight line through the values over time,
  weighted by 1/sigma^2 when every sigma is known, with its 1-sigma from the fit's
  covariance. Stated only over a span that supports a rate per year: two dated
  calibrations at least `MIN_DRIFT_SPAN_DAYS` apart (30 minutes of runs give no drift per
  year: the table says why instead); failed calibrations are left out of the fit.

The printed table marks each calibration that failed its verdict, ran on the simulators,
or whose record is not the run's own result (a stand-in re-solve, a promoted result), and
prints each coefficient's values with the digits that show their changes.
"""

from __future__ import annotations

import csv
import dataclasses
import datetime as dt
import io
import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.log.names import output_path, safe_name
from bench.model.families import canonical_names
from bench.records.store import Records, RecordsError

SECONDS_PER_YEAR = 365.25 * 86400.0
#: the shortest span of calibrations a drift per year is stated over
MIN_DRIFT_SPAN_DAYS = 30.0
#: the fewest and most significant digits a value is printed with
MIN_DIGITS, MAX_DIGITS = 6, 15


@dataclass(frozen=True)
class Point:
    """One calibration of one coefficient."""

    run_id: str
    when: dt.datetime | None
    software_version: str
    verdict: str | None
    value: float
    sigma: float | None
    budget: dict | None


@dataclass(frozen=True)
class Calibration:
    """One calibration run of the unit (its record of truth: `Records.history_rows`)."""

    run_id: str
    when: dt.datetime | None
    software_version: str
    verdict: str | None
    origin: str | None = "run"        # the record's origin: run, re-solve (its own result not recorded), ...
    promoted: bool = False            # a user made this result the run's record (`bench db promote`)
    simulated: bool = False           # a run on the simulators, not on the bench


@dataclass(frozen=True, eq=False)
class CoefficientHistory:
    """One coefficient over the unit's calibrations, with its changes and drift.

    Columns, not one object per value (a unit with 10,000 calibrations has 300,000 values):
    `index` picks this coefficient's calibrations (ascending) out of the unit's `calibrations`,
    `values` and `sigmas` (NaN: unknown) are theirs, `years` their time in years since the
    unit's first dated calibration (NaN: undated). `points` gives them one by one.
    """

    name: str
    unit: str
    calibrations: list[Calibration]
    index: np.ndarray
    values: np.ndarray
    sigmas: np.ndarray
    years: np.ndarray
    budgets: list[dict | None] | None = None
    failed_all: np.ndarray | None = None      # per calibration of the unit: its verdict is fail (None: work it out)

    @property
    def points(self) -> list[Point]:
        """The calibrations of this coefficient one by one, oldest first."""
        budgets = self.budgets or [None] * len(self.index)
        return [Point(cal.run_id, cal.when, cal.software_version, cal.verdict, v, None if math.isnan(s) else s, b)
                for cal, v, s, b in zip((self.calibrations[k] for k in self.index.tolist()), self.values.tolist(),
                                        self.sigmas.tolist(), budgets)]

    def _changes(self) -> tuple[np.ndarray, np.ndarray]:
        a, b = self.sigmas[:-1], self.sigmas[1:]
        unknown = np.isnan(a) | np.isnan(b) | ((a == 0) & (b == 0))
        with np.errstate(divide="ignore", invalid="ignore"):
            z = np.diff(self.values) / np.hypot(a, b)
        return z, unknown

    def changes_sigma(self) -> list[float | None]:
        """z of each calibration against the one before (the first has none)."""
        z, unknown = self._changes()
        return [None if u else x for x, u in zip(z.tolist(), unknown.tolist())]

    def _failed(self) -> np.ndarray:
        failed_all = self.failed_all if self.failed_all is not None else _failed_all(self.calibrations)
        return failed_all[self.index]

    def drift_note(self) -> str | None:
        """Why no drift per year is stated (None: one is)."""
        used = ~np.isnan(self.years) & ~self._failed()
        if np.count_nonzero(used) < 2:
            return ("needs two dated calibrations" + (" that did not fail" if self._failed().any() else ""))
        span_days = float(np.ptp(self.years[used])) * SECONDS_PER_YEAR / 86400.0
        if span_days < MIN_DRIFT_SPAN_DAYS:
            return (f"not stated: the calibrations span {_span(span_days)}, a drift per year needs at least "
                    f"{MIN_DRIFT_SPAN_DAYS:g} days")
        return None

    def drift_per_year(self) -> tuple[float, float | None] | None:
        """(slope per year, its 1-sigma or None), or None where `drift_note` says why (fewer than two dated
        calibrations that did not fail, or a span shorter than `MIN_DRIFT_SPAN_DAYS`)."""
        if self.drift_note() is not None:
            return None
        used = ~np.isnan(self.years) & ~self._failed()
        years = self.years[used] - self.years[used][0]
        values, sigmas = self.values[used], self.sigmas[used]
        weighted = bool(np.all(sigmas > 0))       # NaN (unknown) compares False
        w = 1.0 / sigmas ** 2 if weighted else np.ones(len(years))
        design = np.column_stack([np.ones_like(years), years])
        normal = design.T @ (design * w[:, None])
        coef = np.linalg.solve(normal, design.T @ (w * values))
        if weighted:
            cov = np.linalg.inv(normal)
        elif len(years) > 2:    # unweighted: the scatter about the line gives the noise
            resid = values - design @ coef
            cov = np.linalg.inv(normal) * float(resid @ resid) / (len(years) - 2)
        else:
            return float(coef[1]), None
        return float(coef[1]), float(math.sqrt(cov[1, 1]))

    def digits(self) -> int:
        """Significant digits that show the smallest change between consecutive values (two digits of it), or
        the sigma's digits for a single value; `MIN_DIGITS`..`MAX_DIGITS` (36012.5 on every row hid changes of
        0.03)."""
        finite = self.values[np.isfinite(self.values)]
        top = float(np.max(np.abs(finite))) if finite.size else 0.0
        if top == 0.0:
            return MIN_DIGITS
        steps = np.abs(np.diff(finite))
        steps = steps[steps > 0]
        sigmas = self.sigmas[np.isfinite(self.sigmas) & (self.sigmas > 0)]
        scale = float(steps.min()) if steps.size else float(sigmas.min()) if sigmas.size else 0.0
        if scale == 0.0:
            return MIN_DIGITS
        digits = math.floor(math.log10(top)) - math.floor(math.log10(scale)) + 2
        return max(MIN_DIGITS, min(MAX_DIGITS, digits))


@dataclass(frozen=True)
class UnitHistory:
    serial: str
    model: str | None
    coefficients: list[CoefficientHistory]
    calibrations: list[Calibration] = dataclasses.field(default_factory=list)

    @property
    def runs(self) -> list[str]:
        """The run ids of the calibrations that have any of the coefficients, oldest first."""
        used = np.zeros(len(self.calibrations), dtype=bool)
        for c in self.coefficients:
            used[c.index] = True
        return [cal.run_id for cal, u in zip(self.calibrations, used.tolist()) if u]

    def to_json(self) -> dict:
        table: dict[str, dict] = {}
        for c in self.coefficients:
            drift = c.drift_per_year()
            table[c.name] = {
                "unit": c.unit,
                "calibrations": [{"run_id": p.run_id, "when_utc": _iso(p.when), "software_version": p.software_version,
                                  "verdict": p.verdict, "value": p.value, "sigma": p.sigma, "budget": p.budget,
                                  "marks": _marks(cal)}
                                 for p, cal in zip(c.points, (c.calibrations[k] for k in c.index.tolist()))],
                "changes_sigma": c.changes_sigma(),
                "drift_per_year": None if drift is None else {"value": drift[0], "sigma": drift[1]},
                "drift_note": c.drift_note()}
        return {"serial": self.serial, "model": self.model, "coefficients": table}


def _failed_all(calibrations: list[Calibration]) -> np.ndarray:
    return np.array([cal.verdict == "fail" for cal in calibrations], dtype=bool)


def _iso(when: dt.datetime | None) -> str | None:
    return None if when is None else when.replace(microsecond=0).isoformat() + "Z"


def unit_history(records: Records, serial: str, names: list[str] | None = None,
                 model: str | None = None, budgets: bool = True) -> UnitHistory:
    """The unit's history (RecordsError: no such serial, or one serial on several models without `model`);
    `budgets=False` leaves each value's budget out (None), which the printed table does not show."""
    models = records.unit_models(serial)
    if not models:
        raise RecordsError(f"no unit with serial {serial!r} in the records")
    if model is None and len(models) > 1:
        raise RecordsError(f"serial {serial!r} is recorded for {len(models)} models ({', '.join(models)}): "
                           f"say which with --model")
    if model is not None and model not in models:
        raise RecordsError(f"no unit {model!r} with serial {serial!r} in the records (models: {', '.join(models)})")
    runs, values = records.history_rows(serial, model, names, budgets=budgets)
    calibrations = [Calibration(run_id, when, software, verdict, origin, bool(promoted), mode == "simulator")
                    for _, run_id, when, software, verdict, origin, promoted, mode in runs]
    position = {row[0]: k for k, row in enumerate(runs)}
    first = next((cal.when for cal in calibrations if cal.when is not None), None)
    years = np.array([math.nan if cal.when is None or first is None else
                      (cal.when - first).total_seconds() / SECONDS_PER_YEAR for cal in calibrations])
    out = []
    failed_all = _failed_all(calibrations)
    if values:
        # columns, grouped by coefficient and in calibration order with one sort (300,000 values, not a loop each)
        result_ids, value_names, numbers, sigmas, units, budget_list = zip(*values)
        where = np.array([position[r] for r in result_ids], dtype=np.intp)
        # the rows come by name: a group starts where the name changes; within it, calibration order
        starts = [0, *(k for k in range(1, len(value_names)) if value_names[k] != value_names[k - 1])]
        groups = {value_names[a]: a + np.argsort(where[a:b], kind="stable")
                  for a, b in zip(starts, [*starts[1:], len(value_names)])}
        numbers_array = np.array(numbers, dtype=float)
        sigmas_array = np.array([math.nan if x is None else x for x in sigmas], dtype=float)
        for n in names or _canonical_order(list(groups)):
            g = groups.get(n)
            if g is None:
                continue
            index = where[g]
            out.append(CoefficientHistory(n, units[g[0]], calibrations, index, numbers_array[g], sigmas_array[g],
                                          years[index], [budget_list[k] for k in g.tolist()] if budgets else None,
                                          failed_all))
    return UnitHistory(serial, model or models[0], out, calibrations)


def _canonical_order(names: list[str]) -> list[str]:
    canonical = [n for n in canonical_names() if n in names]
    return canonical + sorted(set(names) - set(canonical))


def _g(x: float | None) -> str:
    return "-" if x is None else f"{x:.6g}"


def _span(days: float) -> str:
    if days < 1.0 / 24.0:
        return f"{days * 1440.0:.0f} min"
    if days < 2.0:
        return f"{days * 24.0:.1f} h"
    return f"{days:.1f} days"


def _marks(cal: Calibration) -> list[str]:
    """What a reader of the history must know of a calibration: it failed, ran on the simulators, or its record
    is not the run's own result."""
    marks = ["FAILED"] if cal.verdict == "fail" else []
    if cal.simulated:
        marks.append("simulated")
    if cal.promoted:
        marks.append("promoted")
    elif cal.origin not in ("run", None):
        marks.append(f"{cal.origin} (its own result not recorded)")
    return marks


def drift_text(c: CoefficientHistory) -> str:
    """The history's drift line of one coefficient: the drift per year, or why none is stated."""
    drift = c.drift_per_year()
    if drift is None:
        return f"drift: {c.drift_note()}"
    failed = int(np.count_nonzero(c._failed()))
    return (f"drift: {_g(drift[0])} {c.unit} per year" + ("" if drift[1] is None else f" +- {_g(drift[1])}")
            + (f" ({failed} failed calibration(s) left out)" if failed else ""))


def format_history(history: UnitHistory) -> str:
    """The table `bench db history` prints: per coefficient, each calibration, its change, the drift."""
    lines = [f"unit {history.model} / {history.serial}: {len(history.runs)} calibration(s)"]
    # formatted once per calibration, then per value in one comprehension per column: 300,000 values in a second
    heads = [f"  {(_iso(cal.when) or '-'):20} {cal.run_id[:28]:28} " for cal in history.calibrations]
    notes = [("  " + ", ".join(m)) if (m := _marks(cal)) else "" for cal in history.calibrations]
    for c in history.coefficients:
        digits = c.digits()
        width = max(14, digits + 7)
        lines.append(f"\n{c.name} [{c.unit}]  {drift_text(c)}")
        lines.append(f"  {'when (UTC)':20} {'run':28} {'value':>{width}} {'sigma':>11} {'change':>9}")
        z, unknown = c._changes()
        index = c.index.tolist()
        rows, values, row_notes = [heads[k] for k in index], c.values.tolist(), [notes[k] for k in index]
        value = f"%{width}.{digits}g"
        # "%+5.2f sig" is f"{z:+.2f} sig" right-aligned in 9
        if not unknown.any() and not np.isnan(c.sigmas).any():      # the usual case: one format per line
            sigmas = c.sigmas.tolist()
            lines.append(f"%s{value} %11.6g          %s" % (rows[0], values[0], sigmas[0], row_notes[0]))
            lines += [f"%s{value} %11.6g %+5.2f sig%s" % row
                      for row in zip(rows[1:], values[1:], sigmas[1:], z.tolist(), row_notes[1:])]
            continue
        changes = [" " * 9, *(" " * 9 if u else "%+5.2f sig" % x for x, u in zip(z.tolist(), unknown.tolist()))]
        sigma_text = ["%11.6g" % s if s == s else "          -" for s in c.sigmas.tolist()]     # NaN: unknown
        lines += [f"%s{value} %s %s%s" % row for row in zip(rows, values, sigma_text, changes, row_notes)]
    return "\n".join(lines) + "\n"


def history_csv(history: UnitHistory) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["serial", "coefficient", "unit", "when_utc", "run_id", "software_version", "verdict", "value",
                     "sigma", "change_sigma", "marks"])
    for c in history.coefficients:
        for p, z, k in zip(c.points, [None, *c.changes_sigma()], c.index.tolist()):
            writer.writerow([history.serial, c.name, c.unit, _iso(p.when) or "", p.run_id, p.software_version,
                             p.verdict or "", repr(p.value), "" if p.sigma is None else repr(p.sigma),
                             "" if z is None else f"{z:.4f}", "; ".join(_marks(c.calibrations[k]))])
    return buf.getvalue()


def write_history(history: UnitHistory, out_dir: str | Path) -> list[Path]:
    """`<serial>.history.json`, `.history.csv` and `.history.png` (value +- 1 sigma over time) in `out_dir`."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = safe_name(history.serial) or "unit"
    json_path = output_path(out_dir, f"{stem}.history.json")    # a serial never names a path outside out_dir
    json_path.write_text(json.dumps(history.to_json(), indent=2, allow_nan=False) + "\n", encoding="utf-8")
    csv_path = output_path(out_dir, f"{stem}.history.csv")
    csv_path.write_text(history_csv(history), encoding="utf-8")
    png_path = output_path(out_dir, f"{stem}.history.png")
    _plot(history, png_path)
    return [json_path, csv_path, png_path]


def _plot(history: UnitHistory, path: Path) -> None:
    from bench.report.plots import plt  # matplotlib, heavy: only when a plot is written

    n = max(1, len(history.coefficients))
    cols = min(3, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 2.6 * rows), squeeze=False)
    try:
        for ax, c in zip(axes.flat, history.coefficients):
            dated = [p for p in c.points if p.when is not None]
            ax.errorbar([p.when for p in dated], [p.value for p in dated],
                        yerr=[0.0 if p.sigma is None else p.sigma for p in dated], fmt="o-", capsize=3, ms=3)
            ax.set_title(f"{c.name} [{c.unit}]", fontsize=9)
            ax.tick_params(labelsize=7)
            for label in ax.get_xticklabels():
                label.set_rotation(30)
        for ax in list(axes.flat)[len(history.coefficients):]:
            ax.set_visible(False)
        fig.suptitle(f"{history.model} / {history.serial}: coefficients +- 1 sigma over time", fontsize=10)
        fig.tight_layout()
        fig.savefig(path, dpi=90)
    finally:
        plt.close(fig)


__all__ = ["Calibration", "CoefficientHistory", "MIN_DRIFT_SPAN_DAYS", "Point", "UnitHistory", "drift_text",
           "format_history", "history_csv", "unit_history", "write_history"]
