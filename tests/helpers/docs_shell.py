"""The documentation's shell commands as a reader runs them: in bash, in a folder holding the example
configurations, with `bench` the worktree's `python -m bench.cli` (tests/architecture/test_docs.py), and a run that a
page shows and an end-to-end test checks too, recorded once (`documented_thermal_run`, tests/conftest.py)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = ("bench.example.toml", "thermal.example.toml", "lab.example.toml", "multi-imu.example.toml")

#: docs/how-to/thermal.md's chamber-driven run: one `bench run` soaks and calibrates at four temperatures (minutes of
#: CPU). tests/e2e/test_thermal_chamber_run.py checks what it writes; the page's test runs its other commands on it.
THERMAL_RUN_COMMAND = "bench run --config thermal.example.toml --sim --out runs/thermal-run"


def with_examples(folder: Path) -> Path:
    """`folder` with a copy of the example configurations (the docs' commands name them); returns it."""
    for example in EXAMPLES:
        shutil.copyfile(REPO / example, folder / example)
    return folder


def run_bench_shell(script: str, folder: Path) -> subprocess.CompletedProcess[str]:
    """`script` run by bash in `folder` (`set -e`), `pip install` commands left out, `bench` the worktree's CLI,
    records into `folder`/records.sqlite."""
    script = "\n".join(line for line in script.splitlines() if not line.lstrip().startswith("pip install"))
    script = re.sub(r"^pip install [^&\n]*&& ", "", script, flags=re.M)
    env = {**os.environ, "PYTHONPATH": str(REPO), "BENCH_DB": str(folder / "records.sqlite")}
    shim = f'bench() {{ {shlex.quote(sys.executable)} -m bench.cli "$@"; }}\nset -e\n'
    return subprocess.run(["bash", "-c", shim + script], cwd=folder, env=env, capture_output=True, text=True,
                          timeout=900)


def same_command(line: str, command: str) -> bool:
    """Whether a shell line is `command` (words compared; a trailing comment ignored)."""
    try:
        return shlex.split(line, comments=True) == shlex.split(command)
    except ValueError:          # not one command (an open quote: a line of a longer one)
        return False
