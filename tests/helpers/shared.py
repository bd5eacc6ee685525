"""Recordings shared by many tests (session or module fixtures) are read, never written: `share(folder)` takes a
fingerprint of every file below `folder`, and `changed_shared()` says which shared folders a test changed since.

tests/conftest.py checks after every test, so the test that wrote into a shared folder is the one that fails (and
not, later, another test that read what it left). A file mode would not do it: the tests may run as root.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")

#: shared folder -> its files' (relative path, size, modification time in ns) when it was shared
_SHARED: dict[Path, frozenset[tuple[str, int, int]]] = {}


def _fingerprint(folder: Path) -> frozenset[tuple[str, int, int]]:
    out = set()
    for path in folder.rglob("*"):
        stat = path.lstat()
        out.add((str(path.relative_to(folder)), stat.st_size if path.is_file() else -1, stat.st_mtime_ns))
    return frozenset(out)


def share(folder: Path) -> Path:
    """Mark `folder` (a finished recording) as shared and read-only from now on; returns it."""
    folder = Path(folder)
    _SHARED[folder] = _fingerprint(folder)
    return folder


def changed_shared() -> list[str]:
    """One line per shared folder whose files changed (added, removed, rewritten) since it was shared."""
    out = []
    for folder, before in _SHARED.items():
        after = _fingerprint(folder) if folder.is_dir() else frozenset()
        if after != before:
            touched = sorted({name for name, _, _ in before ^ after})
            out.append(f"{folder}: {', '.join(touched[:5])}{' ...' if len(touched) > 5 else ''}")
            _SHARED[folder] = after         # reported once, by the test that changed it
    return out


def recorded_once(tmp_path_factory, name: str, record: Callable[[Path], T]) -> tuple[Path, T]:
    """A session fixture's recording, made once per test session however many pytest-xdist workers ask for it:
    (its folder, what `record(folder)` returned, which must survive a JSON round trip).

    Serial, this is `record(tmp_path_factory.mktemp(name))`. Under xdist the first worker to ask records into a
    folder of the session's temporary root (the parent of every worker's own, new for each session) while holding
    an exclusive lock on a file beside it; the others wait for the lock and read the `.done.json` it leaves. A
    recording that failed leaves no `.done.json`, so the next worker to ask records it again (and fails on its own).
    The folder is returned unshared: the fixture `share`s it when it has looked at it."""
    if os.environ.get("PYTEST_XDIST_WORKER") is None:
        folder = tmp_path_factory.mktemp(name)
        return folder, record(folder)
    root = tmp_path_factory.getbasetemp().parent
    folder, done = root / name, root / f"{name}.done.json"
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)        # released when the file closes
        if not done.exists():
            shutil.rmtree(folder, ignore_errors=True)    # a failed worker's half
            folder.mkdir()
            value = record(folder)
            done.write_text(json.dumps(value), encoding="utf-8")
        return folder, json.loads(done.read_text(encoding="utf-8"))
