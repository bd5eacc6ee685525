"""A `bench sim ...` command run in a child process, and reading its output (tests of the simulators' CLIs and
benchmarks/rig_speed.py)."""

from __future__ import annotations

import subprocess
import sys

from tests.helpers.run import REPO


def start_sim(*args: str) -> subprocess.Popen:
    """`bench sim ARGS...` in a child process, stdin, stdout and stderr piped (text)."""
    return subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", *args], cwd=REPO, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def read_until(proc: subprocess.Popen, marker: str, lines: int = 20) -> list[str]:
    """The process's lines up to the one holding `marker` (bounded: at most `lines` lines)."""
    assert proc.stdout is not None and proc.stderr is not None
    seen = []
    for _ in range(lines):
        line = proc.stdout.readline()
        if not line:
            break
        seen.append(line)
        if marker in line:
            return seen
    stderr = proc.stderr.read() if proc.poll() is not None else ""
    raise AssertionError(f"no {marker!r} in the output: {seen}; stderr: {stderr}")
