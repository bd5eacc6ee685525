"""The shared-recording check of tests/conftest.py (tests/helpers/shared.py): a file added to, rewritten in or
removed from a shared folder is named once, by the check after the test that did it; reading changes nothing.
And `recorded_once`: a session recording made once for all pytest-xdist workers."""

from __future__ import annotations

import json
import os
from types import SimpleNamespace

import pytest

from tests.helpers.shared import changed_shared, recorded_once, share


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


def _recorder(calls: list):
    def record(folder):
        calls.append(folder)
        (folder / "run.mcap").write_bytes(b"log")
        return {"log": "run.mcap", "finished_s": 12.5}
    return record


def test_workers_of_one_session_record_once_and_read_the_same_value(tmp_path, monkeypatch):
    session_root = tmp_path / "pytest-7"
    workers = [SimpleNamespace(getbasetemp=lambda name=name: session_root / name)
               for name in ("popen-gw0", "popen-gw1")]
    for worker in workers:
        worker.getbasetemp().mkdir(parents=True)
    calls: list = []
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")
    first = recorded_once(workers[0], "short-run", _recorder(calls))
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw1")
    second = recorded_once(workers[1], "short-run", _recorder(calls))
    assert calls == [session_root / "short-run"]
    assert first == second == (session_root / "short-run", {"log": "run.mcap", "finished_s": 12.5})
    assert json.loads((session_root / "short-run.done.json").read_text()) == first[1]


def test_a_failed_recording_is_recorded_again_by_the_next_worker(tmp_path, monkeypatch):
    session_root = tmp_path / "pytest-8"
    worker = SimpleNamespace(getbasetemp=lambda: session_root / "popen-gw0")
    worker.getbasetemp().mkdir(parents=True)
    monkeypatch.setenv("PYTEST_XDIST_WORKER", "gw0")

    def fail(folder):
        (folder / "half.mcap").write_bytes(b"lo")
        raise AssertionError("the run failed")

    with pytest.raises(AssertionError, match="the run failed"):
        recorded_once(worker, "noisy", fail)
    calls: list = []
    folder, value = recorded_once(worker, "noisy", _recorder(calls))
    assert calls == [folder] and value["log"] == "run.mcap"
    assert sorted(p.name for p in folder.iterdir()) == ["run.mcap"]      # the failed half is gone


def test_serial_sessions_record_into_a_folder_of_their_own(tmp_path_factory, monkeypatch):
    monkeypatch.delenv("PYTEST_XDIST_WORKER", raising=False)
    calls: list = []
    one, _ = recorded_once(tmp_path_factory, "serial", _recorder(calls))
    two, _ = recorded_once(tmp_path_factory, "serial", _recorder(calls))
    assert calls == [one, two] and one != two and one.parent == tmp_path_factory.getbasetemp()
