"""A benchmark's figures as a JSON file: `record(name, medians_s=..., ratios=..., parameters=...)` writes
benchmarks/results/NAME.json (machine, load, date, commit, parameters, medians, ratios), the latest run of each
benchmark; `python -m bench.cli.docs_gen` renders them into docs/benchmarks.md.

A benchmark script imports it as `results` (its own folder is on sys.path when run as `python benchmarks/x.py`).
`BENCH_RESULTS_DIR` points the files elsewhere (a tiny test run must not replace a real measurement).
"""

from __future__ import annotations

import datetime
import json
import os
import platform
import statistics
import subprocess
from pathlib import Path
from typing import Callable

FORMAT = "turntable-bench/benchmark-result"
RESULTS_DIR = Path(__file__).resolve().parent / "results"


def machine() -> dict:
    """What the figures were measured on."""
    return {"system": platform.system(), "release": platform.release(), "processor": platform.machine(),
            "cpus": os.cpu_count(), "python": platform.python_version()}


def load() -> dict:
    """The load averages when the figures were written (1, 5, 15 min): a shared machine's timings need them."""
    one, five, fifteen = os.getloadavg()
    return {"1min": round(one, 2), "5min": round(five, 2), "15min": round(fifteen, 2)}


def commit() -> str:
    """The repository's commit, "+dirty" when the work tree has changes; "unknown" outside a git checkout."""
    here = Path(__file__).resolve().parent
    try:
        head = subprocess.run(["git", "rev-parse", "--short=12", "HEAD"], cwd=here, capture_output=True, text=True,
                              check=True, timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=here,
                               capture_output=True, text=True, check=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def wall_cpu_medians(times: dict[tuple[str, str], list[tuple[float, float]]], describe: Callable[[str], str],
                     baseline: bool) -> tuple[dict[str, float], dict[str, float]]:
    """(medians, ratios) of (wall s, CPU s) runs by (checkout, case): the medians as "CHECKOUT: DESCRIBE(case),
    wall" and ", CPU"; with `baseline`, each case's CPU ratio this/base."""
    medians: dict[str, float] = {}
    for (name, case), values in times.items():
        medians[f"{name}: {describe(case)}, wall"] = statistics.median(w for w, _ in values)
        medians[f"{name}: {describe(case)}, CPU"] = statistics.median(c for _, c in values)
    cases = list(dict.fromkeys(case for _, case in times))
    ratios = {f"{case} CPU this/base": medians[f"this: {describe(case)}, CPU"] / medians[f"base: {describe(case)}, CPU"]
              for case in cases if baseline}
    return medians, ratios


def record(name: str, *, medians_s: dict[str, float], ratios: dict[str, float] | None = None,
           parameters: dict | None = None, note: str = "", folder: Path | None = None) -> Path:
    """Write benchmark `name`'s figures (medians in seconds by what was timed; ratios by what they compare) as
    FOLDER/NAME.json, replacing the previous one; returns its path."""
    if not name or "/" in name or name.startswith("."):
        raise ValueError(f"a benchmark name is a plain file name, got {name!r}")
    folder = Path(folder or os.environ.get("BENCH_RESULTS_DIR") or RESULTS_DIR)
    document = {"format": FORMAT, "version": 1, "benchmark": name,
                "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
                "commit": commit(), "machine": machine(), "load": load(), "parameters": dict(parameters or {}),
                "medians_s": {key: float(value) for key, value in medians_s.items()},
                "ratios": {key: float(value) for key, value in (ratios or {}).items()}, "note": note}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.json"
    temporary = path.with_name(f".{path.name}.tmp")
    temporary.write_text(json.dumps(document, indent=2) + "\n", encoding="utf-8")
    temporary.replace(path)     # a reader never sees half a file
    return path
