"""The shared-recording check of tests/conftest.py (tests/helpers/shared.py): a file added to, rewritten in or
removed from a shared folder is named once, by the check after the test that did it; reading changes nothing."""

from __future__ import annotations

import os

from tests.helpers.shared import changed_shared, share


def test_reading_a_shared_folder_changes_nothing(tmp_path):
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "a.mcap").write_bytes(b"log")
    share(tmp_path)
    assert (tmp_path / "run" / "a.mcap").read_bytes() == b"log" and sorted(p.name for p in tmp_path.rglob("*"))
    assert changed_shared() == []


def test_a_file_added_rewritten_or_removed_is_named_once(tmp_path):
    log = tmp_path / "run" / "a.mcap"
    log.parent.mkdir()
    log.write_bytes(b"log")
    share(tmp_path)
    (tmp_path / "run" / "a.solved.result.json").write_text("{}")         # a new file beside the log
    changed = changed_shared()
    assert len(changed) == 1 and changed[0].startswith(f"{tmp_path}: ") and "a.solved.result.json" in changed[0]
    assert changed_shared() == []                                         # said once, by the test that did it
    log.write_bytes(b"LOG")                                               # rewritten in place, same size
    os.utime(log, ns=(log.stat().st_atime_ns, log.stat().st_mtime_ns + 1_000_000))
    assert len(changed_shared()) == 1
    log.unlink()
    assert "a.mcap" in changed_shared()[0]
    assert changed_shared() == []
