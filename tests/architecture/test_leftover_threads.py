"""The leftover-thread check of tests/conftest.py: it fails on a leftover project thread, and it
knows the name of every thread bench/ and drivers/ start."""

from __future__ import annotations

import ast
import threading
from pathlib import Path

import pytest

from tests.helpers.threads import PROJECT_THREAD_PREFIXES, check_no_leftover_threads, project_threads

REPO = Path(__file__).resolve().parents[2]


def _started(name: str, release: threading.Event) -> threading.Thread:
    thread = threading.Thread(target=release.wait, args=(10.0,), name=name, daemon=True)
    thread.start()
    return thread


def test_a_project_thread_left_running_fails_the_check_by_name():
    before = project_threads()
    release = threading.Event()
    thread = _started("sim-leftover-probe", release)
    try:
        with pytest.raises(AssertionError, match="'sim-leftover-probe'"):
            check_no_leftover_threads(before, grace_s=0.2)
    finally:
        release.set()
        thread.join(5.0)
    check_no_leftover_threads(before, grace_s=0.2)


def test_a_project_thread_that_ends_within_the_grace_period_passes():
    before = project_threads()
    release = threading.Event()
    thread = _started("bench-tui-probe", release)
    threading.Timer(0.2, release.set).start()
    check_no_leftover_threads(before, grace_s=5.0)
    assert not thread.is_alive()


def test_threads_alive_before_and_other_threads_are_not_blamed():
    release = threading.Event()
    earlier = _started("SimCanImu", release)        # e.g. started by a module-scoped fixture
    threads = [earlier]
    try:
        before = project_threads()
        assert earlier in before
        threads.append(_started("not-a-project-thread", release))
        check_no_leftover_threads(before, grace_s=0.1)
    finally:
        release.set()
        for thread in threads:
            thread.join(5.0)


def _thread_names_in_source():
    """(file:line, static start of the name or None) of every `Thread(...)` and
    `ThreadPoolExecutor(...)` call in bench/ and drivers/."""
    found = []
    for path in sorted([*(REPO / "bench").rglob("*.py"), *(REPO / "drivers").rglob("*.py")]):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        for node in ast.walk(tree):
            if not isinstance(node, ast.Call):
                continue
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", None)
            if called == "Thread":
                keyword, position = "name", None
            elif called == "ThreadPoolExecutor":
                keyword, position = "thread_name_prefix", 1
            else:
                continue
            value = next((k.value for k in node.keywords if k.arg == keyword), None)
            if value is None and position is not None and len(node.args) > position:
                value = node.args[position]
            if isinstance(value, ast.Constant) and isinstance(value.value, str):
                name = value.value
            elif isinstance(value, ast.JoinedStr) and value.values and isinstance(value.values[0], ast.Constant):
                name = value.values[0].value
            else:
                name = None
            found.append((f"{path.relative_to(REPO)}:{node.lineno}", name))
    return found


@pytest.mark.slow
def test_every_thread_the_project_starts_has_a_known_name():
    found = _thread_names_in_source()
    assert found, "no Thread(...) call found in bench/ or drivers/"
    unknown = [(where, name) for where, name in found
               if name is None or not name.startswith(PROJECT_THREAD_PREFIXES)]
    assert not unknown, f"threads unnamed or outside tests/helpers/threads.py's prefixes: {unknown}"
