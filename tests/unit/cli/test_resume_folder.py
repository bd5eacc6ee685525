"""`bench run --resume LOG` keeps one run in one folder (issue 33, item 15): without --out the new log is written
beside the resumed one; an --out elsewhere is honoured with a warning naming how `bench solve` finds the logs."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from bench.cli.run import output_folder
from bench.log.reader import read_log
from tests.helpers.run import cli, config_text


def test_the_output_folder_is_out_then_the_resumed_logs_then_the_configured_one(tmp_path):
    log = str(tmp_path / "first" / "r.mcap")
    assert output_folder("else", log, "runs") == Path("else")
    assert output_folder(None, log, "runs") == tmp_path / "first"
    assert output_folder(None, None, "runs").as_posix() == "runs"


@pytest.fixture
def cut_log(short_run, tmp_path):
    """The short run's log cut at 60 % of its size (a crash mid-run), in a folder of its own, and a configuration
    of the same run whose [output] folder is a third one."""
    first = tmp_path / "first"
    first.mkdir()
    log = first / short_run.log.name
    data = short_run.log.read_bytes()
    log.write_bytes(data[:int(len(data) * 0.6)])
    config = tmp_path / "bench.toml"
    config.write_text(config_text(positions="traditional-12", rotations="traditional-3s6r", dwell_s=1.0)
                      + f'[output]\nfolder = "{(tmp_path / "configured").as_posix()}"\n', encoding="utf-8")
    return log, config


def test_resuming_without_out_writes_beside_the_resumed_log(cut_log, tmp_path):
    log, config = cut_log
    rc, _, stderr = cli(["run", "--config", str(config), "--resume", str(log), "--quiet", "--no-db"])
    assert rc == 0, stderr
    assert "warning" not in stderr
    new = [p for p in log.parent.glob("*.mcap") if p != log]
    assert len(new) == 1 and list(log.parent.glob("*.result.json"))
    assert not (tmp_path / "configured").exists()
    assert read_log(new[0]).metadata["run"]["resumed_units"] != "[]"


def test_resuming_into_another_folder_warns_how_to_solve(cut_log, tmp_path):
    log, config = cut_log
    other = tmp_path / "other"
    rc, stdout, stderr = cli(["run", "--config", str(config), "--resume", str(log), "--out", str(other), "--dry-run"])
    assert rc == 0, stderr
    line = stderr.strip()
    assert len(line.splitlines()) == 1 and "warning" in line and str(log.parent) in line, stderr
    assert f"bench solve {log} NEW.mcap" in line
    # the same folder said another way is no split
    shutil.rmtree(other, ignore_errors=True)
    rc, _, stderr = cli(["run", "--config", str(config), "--resume", str(log), "--out", str(log.parent / "."),
                         "--dry-run"])
    assert rc == 0 and "warning" not in stderr, stderr
