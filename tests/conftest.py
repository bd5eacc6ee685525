"""Fixtures shared by test files (opt-in by name)."""

from __future__ import annotations

import threading
import time

import pytest


@pytest.fixture
def no_leftover_tui_threads():
    """Fails the test if a TUI worker thread (`bench-tui-*`) is still running 5 s after it."""
    yield
    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline:
        left = [t.name for t in threading.enumerate() if t.name.startswith("bench-tui-")]
        if not left:
            return
        time.sleep(0.05)
    raise AssertionError(f"threads left running: {left}")
