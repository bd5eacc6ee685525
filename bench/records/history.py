"""A unit's calibration history: each coefficient over time, its changes in sigma, its drift per year.

`unit_history(records, serial)` reads the unit's latest result of every calibration run
(`Records.history_rows`, oldest first) and computes, per coefficient:

- the change between consecutive calibrations in units of their combined 1-sigma,
  z = (v_k - v_{k-1}) / sqrt(s_k^2 + s_{k-1}^2) (None when a sigma is unknown);
- the drift per year: the slope of a straight line through the values over time,
  weighted by 1/sigma^2 when every sigma is known, with its 1-sigma from the fit's
  covariance (needs two calibrations at different times).
"""

from __future__ import annotations

import csv
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
class CoefficientHistory:
    """One coefficient over the unit's calibrations, with its changes and drift."""

    name: str
    unit: str
    points: list[Point]

    def changes_sigma(self) -> list[float | None]:
        """z of each calibration against the one before (the first has none)."""
        out: list[float | None] = []
        for a, b in zip(self.points, self.points[1:]):
            if a.sigma is None or b.sigma is None or (a.sigma == 0 and b.sigma == 0):
                out.append(None)
            else:
                out.append((b.value - a.value) / math.hypot(a.sigma, b.sigma))
        return out

    def drift_per_year(self) -> tuple[float, float | None] | None:
        """(slope per year, its 1-sigma or None), or None with fewer than two dated calibrations at distinct times."""
        dated = [p for p in self.points if p.when is not None]
        if len(dated) < 2:
            return None
        t0 = dated[0].when
        assert t0 is not None
        years = np.array([(p.when - t0).total_seconds() / SECONDS_PER_YEAR for p in dated])   # type: ignore[operator]
        if np.ptp(years) == 0.0:
            return None
        values = np.array([p.value for p in dated])
        sigmas = [p.sigma for p in dated]
        weighted = all(s is not None and s > 0 for s in sigmas)
        w = np.array([1.0 / s ** 2 for s in sigmas]) if weighted else np.ones(len(dated))    # type: ignore[operator]
        design = np.column_stack([np.ones_like(years), years])
        normal = design.T @ (design * w[:, None])
        coef = np.linalg.solve(normal, design.T @ (w * values))
        if weighted:
            cov = np.linalg.inv(normal)
        elif len(dated) > 2:    # unweighted: the scatter about the line gives the noise
            resid = values - design @ coef
            cov = np.linalg.inv(normal) * float(resid @ resid) / (len(dated) - 2)
        else:
            return float(coef[1]), None
        return float(coef[1]), float(math.sqrt(cov[1, 1]))


@dataclass(frozen=True)
class UnitHistory:
    serial: str
    model: str | None
    coefficients: list[CoefficientHistory]

    @property
    def runs(self) -> list[str]:
        seen: dict[str, None] = {}
        for c in self.coefficients:
            for p in c.points:
                seen.setdefault(p.run_id, None)
        return list(seen)

    def to_json(self) -> dict:
        table: dict[str, dict] = {}
        for c in self.coefficients:
            drift = c.drift_per_year()
            table[c.name] = {
                "unit": c.unit,
                "calibrations": [{"run_id": p.run_id, "when_utc": _iso(p.when), "software_version": p.software_version,
                                  "verdict": p.verdict, "value": p.value, "sigma": p.sigma, "budget": p.budget}
                                 for p in c.points],
                "changes_sigma": c.changes_sigma(),
                "drift_per_year": None if drift is None else {"value": drift[0], "sigma": drift[1]}}
        return {"serial": self.serial, "model": self.model, "coefficients": table}


def _iso(when: dt.datetime | None) -> str | None:
    return None if when is None else when.replace(microsecond=0).isoformat() + "Z"


def unit_history(records: Records, serial: str, names: list[str] | None = None,
                 model: str | None = None) -> UnitHistory:
    """The unit's history (RecordsError: no such serial, or one serial on several models without `model`)."""
    models = records.unit_models(serial)
    if not models:
        raise RecordsError(f"no unit with serial {serial!r} in the records")
    if model is None and len(models) > 1:
        raise RecordsError(f"serial {serial!r} is recorded for {len(models)} models ({', '.join(models)}): "
                           f"say which with --model")
    if model is not None and model not in models:
        raise RecordsError(f"no unit {model!r} with serial {serial!r} in the records (models: {', '.join(models)})")
    by_name: dict[str, tuple[str, list[Point]]] = {}
    for run_id, when, software, verdict, name, value, sigma, unit, budget in records.history_rows(serial, model, names):
        by_name.setdefault(name, (unit, []))[1].append(Point(run_id, when, software, verdict, value, sigma, budget))
    order = names or _canonical_order(list(by_name))
    return UnitHistory(serial, model or models[0],
                       [CoefficientHistory(n, by_name[n][0], by_name[n][1]) for n in order if n in by_name])


def _canonical_order(names: list[str]) -> list[str]:
    canonical = [n for n in canonical_names() if n in names]
    return canonical + sorted(set(names) - set(canonical))


def _g(x: float | None) -> str:
    return "-" if x is None else f"{x:.6g}"


def format_history(history: UnitHistory) -> str:
    """The table `bench db history` prints: per coefficient, each calibration, its change, the drift."""
    runs = history.runs
    lines = [f"unit {history.model} / {history.serial}: {len(runs)} calibration(s)"]
    for c in history.coefficients:
        drift = c.drift_per_year()
        drift_text = ("drift: needs two dated calibrations" if drift is None else
                      f"drift: {_g(drift[0])} {c.unit} per year" + ("" if drift[1] is None else f" +- {_g(drift[1])}"))
        lines.append(f"\n{c.name} [{c.unit}]  {drift_text}")
        lines.append(f"  {'when (UTC)':20} {'run':28} {'value':>14} {'sigma':>11} {'change':>9}")
        for p, z in zip(c.points, [None, *c.changes_sigma()]):
            lines.append(f"  {(_iso(p.when) or '-'):20} {p.run_id[:28]:28} {_g(p.value):>14} {_g(p.sigma):>11} "
                         f"{'' if z is None else f'{z:+.2f} sig':>9}")
    return "\n".join(lines) + "\n"


def history_csv(history: UnitHistory) -> str:
    buf = io.StringIO()
    writer = csv.writer(buf, lineterminator="\n")
    writer.writerow(["serial", "coefficient", "unit", "when_utc", "run_id", "software_version", "verdict", "value",
                     "sigma", "change_sigma"])
    for c in history.coefficients:
        for p, z in zip(c.points, [None, *c.changes_sigma()]):
            writer.writerow([history.serial, c.name, c.unit, _iso(p.when) or "", p.run_id, p.software_version,
                             p.verdict or "", repr(p.value), "" if p.sigma is None else repr(p.sigma),
                             "" if z is None else f"{z:.4f}"])
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


__all__ = ["CoefficientHistory", "Point", "UnitHistory", "format_history", "history_csv", "unit_history",
           "write_history"]
