"""What a report says about its run, once for the Markdown and the HTML report."""

from __future__ import annotations

from typing import Any

_RUN_KEYS = ("run_id", "mode", "operator", "started_utc", "finished_utc", "state", "software_version",
             "positions", "rotations", "log")
#: site keys -> (label, unit); a key without a value (local_g None: computed from latitude and height) is left out
_SITE = {"latitude_deg": ("latitude", "deg"), "height_m": ("height", "m"), "local_g": ("local g", "m/s^2")}


def run_facts(run: dict[str, Any]) -> list[tuple[str, str]]:
    """(label, plain text) rows: the run's identity, every log it was solved from, IMU and site."""
    rows = [(key.replace("_", " "), str(run[key])) for key in _RUN_KEYS if run.get(key) not in (None, "")]
    logs = run.get("logs")
    if isinstance(logs, list) and len(logs) > 1:        # a resumed run: every log, not just the last one
        rows.append(("logs", ", ".join(map(str, logs))))
    imu = run.get("imu")
    if isinstance(imu, dict) and any(imu.get(k) for k in ("model", "serial")):
        rows.append(("IMU", " ".join(str(imu[k]) for k in ("model", "serial") if imu.get(k))))
    site = run.get("site")
    site_text = describe_site(site) if isinstance(site, dict) else ""
    if site_text:
        rows.append(("site", site_text))
    return rows


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
