"""What a report says about its run, once for the Markdown and the HTML report."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from bench.acceptance.verdict import stored_headline, stored_outcome
from bench.model.run_section import RunInfo
from bench.model.verdict_section import VerdictSection

_RUN_KEYS = ("run_id", "mode", "operator", "started_utc", "finished_utc", "state", "software_version",
             "positions", "rotations", "log")
#: site keys -> (label, unit); a key without a value (local_g None: computed from latitude and height) is left out
_SITE = {"latitude_deg": ("latitude", "deg"), "height_m": ("height", "m"), "local_g": ("local g", "m/s^2")}


def run_facts(run: RunInfo) -> list[tuple[str, str]]:
    """(label, plain text) rows: the run's identity, every log it was solved from, IMU and site."""
    rows = [(key.replace("_", " "), str(getattr(run, key))) for key in _RUN_KEYS if getattr(run, key) not in (None, "")]
    logs = run.logs
    if logs is not None and len(logs) > 1:          # a resumed run: every log, not just the last one
        rows.append(("logs", ", ".join(map(str, logs))))
    imu = run.imu
    if imu is not None and (imu.model or imu.serial):
        rows.append(("IMU", " ".join(str(v) for v in (imu.model, imu.serial) if v)))
    site = run.site
    site_text = describe_site(site) if site is not None else ""
    if site_text:
        rows.append(("site", site_text))
    return rows


def lost_samples_note(run: RunInfo) -> str | None:
    """The line saying how many IMU samples were lost outside every dwell and turn window the solve uses (None: none
    were, or the result does not record it): they fail no quality check, only an [acceptance] `max_lost_samples`."""
    outside = run.lost_samples.outside_windows if run.lost_samples is not None else None
    if outside is None or outside <= 0:
        return None
    return (f"{outside} IMU sample{'s' if outside != 1 else ''} lost outside every dwell and turn window the solve "
            "uses (while the table moved or settled, or in a step a subset leaves out): no observation uses them, so "
            "no quality check fails (an [acceptance] max_lost_samples counts them)")


def describe_site(site: dict[str, Any]) -> str:
    """'latitude 30.27 deg, height 10 m' (keys without a value left out, unknown keys as they are)."""
    parts = []
    for key, value in site.items():
        if value in (None, ""):
            continue
        label, unit = _SITE.get(key, (key.replace("_", " "), ""))
        parts.append(f"{label} {value:g} {unit}".rstrip() if isinstance(value, (int, float))
                     and not isinstance(value, bool) else f"{label} {value} {unit}".rstrip())
    return ", ".join(parts)


#: budget components in report order, with their short column titles
BUDGET_COLUMNS = (("noise", "noise (A)"), ("bias instability", "bias instab. (B)"),
                  ("turntable pointing", "turntable (B)"), ("local gravity", "gravity (B)"),
                  ("latitude", "latitude (B)"), ("count resolution", "resolution (B)"),
                  ("turn angle", "turn angle (B)"), ("unexplained scatter", "unexplained (fallback)"))
#: the budget's warning when the solve has turns and their angle error is not known
TURN_ANGLE_MISSING = ("the turns' angle error (the table's position repeatability at their ends) is NOT included: "
                      "the gyro scale factors' and axes' uncertainties leave it out (configure [table] "
                      "turn_angle_error_arcsec)")


def budget_notes(result) -> list[str]:
    """Plain-text lines above the budget table: k, the table's part (or that it is missing), inconsistencies."""
    u = result.quality.uncertainty
    if u is None:
        return ["This result has no uncertainty budget (written before result version 2): its sigma covers the "
                "sample noise only."]
    k = u.get("k", 2)
    lines = [f"sigma is the combined standard uncertainty (root-sum-square of the components); U = {k:g} sigma is "
             f"the expanded uncertainty (k = {k:g}). Type A: from the data; Type B: from what is known of the "
             "equipment."]
    table = (u.get("inputs") or {}).get("table")
    if u.get("table_included") and isinstance(table, dict):
        lines.append(f"Turntable part from {table.get('source', '?')}.")
    else:
        lines.append("WARNING: the turntable's pointing error is NOT included: the uncertainties cover the IMU "
                     "alone (configure [table] pointing_accuracy_arcsec or [table] check).")
    if turn_angle_missing(u):
        lines.append(f"WARNING: {TURN_ANGLE_MISSING}.")
    for c in u.get("consistency", []):
        if isinstance(c, dict) and not c.get("consistent", True):
            lines.append(f"Residuals of the {c.get('fit')} {c.get('sensor')} fit are inconsistent with the budget "
                         f"(chi2 {c.get('chi2')} on {c.get('dof')} dof), driven by {', '.join(c.get('drivers', []))}: "
                         f"widened by {c.get('scale')} as a fallback.")
    return lines


def budget_flags(result) -> list[str]:
    """Short lines for a narrow screen (the TUI's Results): where the table's part came from or that it is
    NOT included, and every fit whose residuals the budget does not explain (unexplained scatter)."""
    u = result.quality.uncertainty
    if u is None:
        return ["no uncertainty budget (a result before version 2): sigma covers the sample noise only"]
    table = (u.get("inputs") or {}).get("table")
    if u.get("table_included") and isinstance(table, dict):
        lines = [f"turntable part: {table.get('source', '?')}"]
    else:
        lines = ["WARNING: turntable pointing NOT included: sigma and U cover the IMU alone "
                 "([table] pointing_accuracy_arcsec or check)"]
    if turn_angle_missing(u):
        lines.append("WARNING: turn angle error NOT included ([table] turn_angle_error_arcsec)")
    for c in u.get("consistency", []):
        if isinstance(c, dict) and not c.get("consistent", True):
            ratio = (f"chi2/dof {c['chi2'] / c['dof']:.3g}, " if isinstance(c.get("chi2"), (int, float))
                     and c.get("dof") else "")
            lines.append(f"UNEXPLAINED SCATTER: {c.get('fit')} {c.get('sensor')} residuals ({ratio}driven by "
                         f"{', '.join(map(str, c.get('drivers', [])))}): widened x{c.get('scale', 1):.3g}")
    return lines


def turn_angle_missing(u: dict[str, Any]) -> bool:
    """The solve had turns (a gyro fit) and no turn-angle figure (results before it say nothing)."""
    has_turns = any(isinstance(c, dict) and c.get("fit") == "gyros" for c in u.get("consistency", []))
    return has_turns and u.get("turn_angle_included") is False


def budget_table(result) -> tuple[list[str], list[list[float | None]], list[str]]:
    """(column titles, per coefficient the component sigmas then sigma and U, names); empty without budgets."""
    coefs = {n: c for n, c in result.coefficients.items() if c.budget is not None}
    if not coefs:
        return [], [], []
    used = [key for key, _ in BUDGET_COLUMNS if any(key in c.budget for c in coefs.values())]
    titles = [title for key, title in BUDGET_COLUMNS if key in used] + ["sigma", "U"]
    rows = [[c.budget.get(key) for key in used] + [c.sigma, c.expanded] for c in coefs.values()]
    return titles, rows, list(coefs)


#: Why the chi2/dof against the sample noise alone is large, said under those lines when the budget's test follows.
SAMPLE_NOISE_NOTE = ("chi2/dof against the sample noise alone is expected far above 1: it counts only the scatter of "
                     "each dwell's samples, and leaves out what moves a dwell's or a turn's mean far more (the "
                     "table's pointing errors, the bias instability, the count resolution); the residuals against "
                     "the budget's predicted scatter, which includes them, are the test of the fit")


def consistency_lines(result) -> list[str] | None:
    """Per fit, the residual test against the budget's predicted scatter (None: no budget in the result)."""
    u = result.quality.uncertainty
    if u is None or not u.get("consistency"):
        return None
    fits: dict[str, list[dict]] = {}
    for c in u["consistency"]:
        if isinstance(c, dict):
            fits.setdefault(str(c.get("fit")), []).append(c)
    out = []
    for fit, rows in fits.items():
        ratios = ", ".join(f"{c['chi2'] / c['dof']:.3g}" if c.get("chi2") is not None and c.get("dof") else "-"
                           for c in rows)
        verdict = "consistent" if all(c.get("consistent", True) for c in rows) else "INCONSISTENT"
        out.append(f"{fit}: residuals against the budget's predicted scatter, chi2/dof per axis {ratios} "
                   f"(dof {rows[0].get('dof')}): {verdict}")
    return out


@dataclass(frozen=True)
class VerdictView:
    """A result's verdict as both reports show it: the outcome word, the headline, the worst check and every
    check as (kind, text, passed)."""

    outcome: str                    # PASS | FAIL | NOT CHECKED (`stored_outcome`: an older file's by the rule)
    headline: str
    worst: str | None
    checks: list[tuple[str, str, bool]]


def verdict_view(section: VerdictSection | None) -> VerdictView | None:
    """The view of a result's `verdict` (None: the result was not judged)."""
    if section is None:
        return None
    verdict = section.to_dict()         # by the rule of a stored verdict (an older file's too: `stored_outcome`)
    checks = [c for c in verdict.get("checks", []) if isinstance(c, dict)]
    worst = verdict.get("worst")
    return VerdictView(stored_outcome(verdict), stored_headline(verdict), worst if isinstance(worst, str) else None,
                       [(_kind(c), str(c.get("text", c.get("name", ""))), c.get("passed") is True) for c in checks])


def _kind(check: dict[str, Any]) -> str:
    """A stored check's kind; an older file's checks have none: told by their names."""
    kind, name = check.get("kind"), str(check.get("name", ""))
    if isinstance(kind, str) and kind:
        return kind
    return "quality" if name == "quality" else "verification" if name.startswith("verify ") else "acceptance"


def quality_findings(verdict: VerdictSection | None, failures: list[str]) -> list[str]:
    """The run's quality failures as a report lists them: each one the verdict does not count (an [acceptance]
    limit, `max_lost_samples` or `max_residual_sigma`, judges it instead) says so."""
    counted = {str(c.text) for c in (verdict.checks or [] if verdict is not None else [])}
    judged = verdict is not None
    return [f if not judged or f"quality: {f}" in counted else f"{f} (judged by its [acceptance] limit instead)"
            for f in failures]
