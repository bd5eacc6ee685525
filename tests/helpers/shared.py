"""Recordings shared by many tests (session or module fixtures) are read, never written: `share(folder)` takes a
fingerprint of every file below `folder`, and `changed_shared()` says which shared folders a test changed since.

tests/conftest.py checks after every test, so the test that wrote into a shared folder is the one that fails (and
not, later, another test that read what it left). A file mode would not do it: the tests may run as root.
"""

from __future__ import annotations

from pathlib import Path

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
