"""Files given by the user (issue 34 items 3 and 4): no output over an input or a run log, no special file read.

Item 3: `bench apply`, `bench export`, `bench export-can` refuse an output that is one of their
inputs (by device and inode: a hard link counts) or another run's log (unless --force), and
replace an output only once it is written in full. Item 4: a FIFO, a device (/dev/zero) or a
folder given where a file is read is one line, at once (a FIFO never blocks: each command runs
in a subprocess with a timeout), and a JSON file over the cap is refused before it is read.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from bench.files import MAX_INPUT_FILE_BYTES, InputFileError, is_run_log, read_input_bytes, replaced_output
from tests.helpers.run import REPO, cli

TIMEOUT_S = 20


@pytest.fixture(scope="module")
def run(short_run) -> tuple[Path, Path]:
    """A finished short simulated run (the session's): (its log, its result)."""
    return short_run.log, short_run.result


def _digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _one_line(rc: int, stderr: str, prog: str) -> str:
    assert rc == 2, (rc, stderr)
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: "), stderr
    return lines[0]


# -- item 3: outputs --------------------------------------------------------------------------------------

def test_apply_refuses_a_hard_link_to_its_log(run, tmp_path):
    log, result = run
    alias = tmp_path / "alias.mcap"
    os.link(log, alias)
    before = _digest(log)
    rc, _, err = cli(["apply", str(result), str(log), "--out", str(alias), "--quiet"])
    assert "a file this command reads" in _one_line(rc, err, "bench apply")
    assert _digest(log) == before and os.path.samefile(log, alias)


def test_apply_refuses_another_runs_log_unless_forced(run, tmp_path):
    log, result = run
    other = tmp_path / "other_run.mcap"
    other.write_bytes(log.read_bytes())
    before = _digest(other)
    rc, _, err = cli(["apply", str(result), str(log), "--out", str(other), "--quiet"])
    assert "is a run log" in _one_line(rc, err, "bench apply")
    assert _digest(other) == before
    rc, _, err = cli(["apply", str(result), str(log), "--out", str(other), "--quiet", "--force"])
    assert rc == 0, err
    assert not is_run_log(other)    # replaced by the compensated samples, as asked
    assert list(tmp_path.glob(".*partial*")) == []


@pytest.mark.slow
def test_apply_rewrites_its_own_output(run, tmp_path):
    """A compensated MCAP is not a run log: running apply again replaces it without --force."""
    log, result = run
    out = tmp_path / "comp.mcap"
    for _ in range(2):
        rc, _, err = cli(["apply", str(result), str(log), "--out", str(out), "--quiet"])
        assert rc == 0, err
    assert not is_run_log(out)


def test_export_refuses_to_write_over_the_result_it_reads(run, tmp_path):
    _, result = run
    copy = tmp_path / "cal.result.json"
    copy.write_bytes(result.read_bytes())
    before = _digest(copy)
    rc, _, err = cli(["export", str(copy), "--out", str(copy), "--format", "json"])
    assert "a file this command reads" in _one_line(rc, err, "bench export")
    assert _digest(copy) == before


def test_export_can_refuses_its_log_and_a_run_log(run, tmp_path):
    log, _ = run
    alias = tmp_path / "frames.asc"
    os.link(log, alias)
    rc, _, err = cli(["export-can", str(log), "--out", str(alias)])
    assert "a file this command reads" in _one_line(rc, err, "bench export-can")
    other = tmp_path / "other.blf"
    other.write_bytes(log.read_bytes())
    rc, _, err = cli(["export-can", str(log), "--out", str(other)])
    assert "is a run log" in _one_line(rc, err, "bench export-can")
    assert _digest(other) == _digest(log)


def test_a_failed_write_leaves_the_old_output_and_no_temporary(tmp_path):
    out = tmp_path / "x.json"
    out.write_text("old", encoding="utf-8")
    with pytest.raises(RuntimeError), replaced_output(out) as temporary:
        temporary.write_text("half", encoding="utf-8")
        raise RuntimeError("disk full")
    assert out.read_text(encoding="utf-8") == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.json"]


# -- item 4: special files and sizes -----------------------------------------------------------------------

def _bench(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bench.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)


@pytest.fixture
def fifo(tmp_path) -> Path:
    path = tmp_path / "log.mcap"
    os.mkfifo(path)
    return path


def test_read_input_refuses_special_files_and_big_files(tmp_path, fifo):
    for path, kind in ((fifo, "a FIFO"), (Path("/dev/zero"), "a character device"), (tmp_path, "a folder")):
        with pytest.raises(InputFileError, match=f"not a regular file \\({kind}\\)"):
            read_input_bytes(path)
    big = tmp_path / "big.json"
    with open(big, "wb") as f:
        f.truncate(MAX_INPUT_FILE_BYTES + 1)    # sparse: nothing written
    with pytest.raises(InputFileError, match="more than a file holds"):
        read_input_bytes(big)


def _commands(log: Path, result: Path, special: Path, out: Path) -> dict[str, list[str]]:
    return {
        "solve": ["solve", str(special), "--out", str(out)],
        "replay": ["replay", str(special), "--quiet"],
        "noise": ["noise", str(special), "--out", str(out)],
        "export-can": ["export-can", str(special), "--out", str(out / "x.asc")],
        "apply": ["apply", str(result), str(special), "--out", str(out / "x.csv")],
        "apply-result": ["apply", str(special), str(log), "--out", str(out / "x.csv")],
        "solve --against": ["solve", str(log), "--against", str(special), "--out", str(out)],
        "check-table --calibration": ["check-table", "--log", str(log), "--calibration", str(special),
                                      "--out", str(out)],
        "noise --calibration": ["noise", str(log), "--calibration", str(special), "--out", str(out)],
        "export": ["export", str(special), "--out", str(out / "x.json")],
        "check-table --log": ["check-table", "--log", str(special), "--out", str(out)],
    }


@pytest.mark.slow
@pytest.mark.parametrize("kind,name", [("fifo", name) for name in _commands(Path(), Path(), Path(), Path())]
                         + [("dev-zero", name) for name in ("solve --against", "check-table --calibration", "export",
                                                            "replay")])
def test_a_special_file_as_input_is_one_line_at_once(name, kind, run, fifo, tmp_path):
    log, result = run
    special = fifo if kind == "fifo" else Path("/dev/zero")
    out = tmp_path / "out"
    out.mkdir()
    proc = _bench(*_commands(log, result, special, out)[name])
    assert proc.returncode == 2, (proc.returncode, proc.stderr)
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a regular file" in lines[0], proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_run_resume_of_a_special_file_is_one_line(fifo, tmp_path):
    from tests.helpers.run import config_text

    config = tmp_path / "bench.toml"
    config.write_text(config_text(), encoding="utf-8")
    for special in (fifo, Path("/dev/zero")):
        proc = _bench("run", "--config", str(config), "--sim", "--resume", str(special), "--out", str(tmp_path),
                      "--quiet", "--no-db")
        assert proc.returncode == 2, proc.stderr
        lines = proc.stderr.strip().splitlines()
        assert len(lines) == 1 and "not a regular file" in lines[0], proc.stderr


def test_a_result_file_over_the_cap_is_refused_before_reading(run, tmp_path):
    log, _ = run
    big = tmp_path / "big.result.json"
    with open(big, "wb") as f:
        f.truncate(MAX_INPUT_FILE_BYTES + 1)
    for argv in (["solve", str(log), "--against", str(big), "--out", str(tmp_path)],
                 ["check-table", "--log", str(log), "--calibration", str(big), "--out", str(tmp_path)],
                 ["noise", str(log), "--calibration", str(big), "--out", str(tmp_path)]):
        rc, _, err = cli(argv)
        assert rc == 2 and "more than a result file holds" in err, (argv, err)


def test_the_run_log_check_reads_only_the_head(run, tmp_path):
    log, result = run
    assert is_run_log(log)
    assert not is_run_log(result) and not is_run_log(Path("/dev/zero")) and not is_run_log(tmp_path)
    json.loads(result.read_text(encoding="utf-8"))


def test_a_table_check_file_of_1_gb_is_refused_before_it_is_read(tmp_path):
    from bench.config.load import ConfigError, parse_config

    big = tmp_path / "t.table-check.json"
    with open(big, "wb") as f:
        f.truncate(1 << 30)    # sparse: read whole it held 2.2 GB
    text = ('format = "turntable-bench/config"\nversion = 1\n[site]\nlatitude_deg = 30.27\n[table]\nurl = "sim"\n'
            f'dialect = "scpi"\ncheck = "{big}"\n[imu]\ninterface = "virtual"\nchannel = "t"\nrate_hz = 200.0\n'
            '[plan]\npositions = "optimal-24"\n')
    with pytest.raises(ConfigError, match="more than a table-check file holds"):
        parse_config(text)
