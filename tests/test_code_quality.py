"""ruff and mypy, configured in pyproject.toml, run by the README's test command.

`CHECKED` lists the code held at zero findings: all of bench, drivers and schedules; ruff also holds the tests
at zero findings (mypy does not check them: the tests are not typed).
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

#: held at zero ruff and mypy findings (the tests are held at zero ruff findings too, but are not typed for mypy)
CHECKED = ["bench", "drivers", "schedules"]


def _run(*command: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", *command], cwd=REPO, capture_output=True, text=True, timeout=600)


def test_ruff_finds_nothing():
    done = _run("ruff", "check", *CHECKED, "tests")
    assert done.returncode == 0, done.stdout + done.stderr


def test_mypy_finds_nothing_in_the_checked_code():
    # mypy follows imports into bench/ as a whole; only findings located in CHECKED count
    done = _run("mypy")
    summary = done.stdout.strip().splitlines()[-1] if done.stdout.strip() else ""
    assert summary.startswith(("Success:", "Found ")), done.stdout + done.stderr   # it ran over the code
    findings = [line for line in done.stdout.splitlines()
                if ": error:" in line and any(line.startswith(path) for path in CHECKED)]
    assert not findings, "\n".join(findings)
