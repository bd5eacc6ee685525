"""`bench solve --archive` (issue 20): an archive of real simulated logs re-solved on a local Dask cluster gives
the very result files one-by-one `bench solve` writes, damaged logs are reported and not fatal, the database
holds every unit's history, and a second pass skips what this software version already solved."""

from __future__ import annotations

import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from bench.records.store import open_records
from tests.helpers.run import REPO, cli, config_text, results_below

SERIALS = ("ARC-A", "ARC-B", "ARC-C")


def _record(folder: Path, serial: str, seed: int) -> Path:
    folder.mkdir(parents=True)
    config = folder / "bench.toml"
    config.write_text(config_text(noise="true", seed=seed, dwell_s=1.0, rate_hz=20.0)
                      .replace('serial = "T-0001"', f'serial = "{serial}"'), encoding="utf-8")
    done = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(config), "--out",
                           str(folder / "run"), "--quiet", "--no-db"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert done.returncode == 0, done.stderr
    log = next((folder / "run").glob("*.mcap"))
    moved = folder / log.name
    shutil.move(str(log), moved)
    shutil.rmtree(folder / "run")
    (folder / "bench.toml").unlink()
    return moved


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> Path:
    """Three IMUs' runs (one of them twice), and a run whose only log is cut, and a file that is not MCAP."""
    root = tmp_path_factory.mktemp("archive")
    jobs = [(root / "a" / "1", "ARC-A", 1), (root / "a" / "2", "ARC-A", 2), (root / "b", "ARC-B", 3),
            (root / "c", "ARC-C", 4), (root / "damaged", "ARC-D", 5)]
    with ThreadPoolExecutor(2) as pool:
        logs = list(pool.map(lambda job: _record(*job), jobs))
    cut = logs[-1]
    data = cut.read_bytes()
    cut.write_bytes(data[: int(len(data) * 0.6)])
    (root / "damaged" / "not-a-log.mcap").write_bytes(b"not an MCAP file\n" * 64)
    return root


@pytest.mark.slow
def test_archive_on_dask_equals_one_by_one_and_records_every_unit(archive, tmp_path):
    one = tmp_path / "one"
    codes = {}
    for log in sorted(archive.rglob("*.mcap")):
        rc, _, _ = cli(["solve", str(log), "--out", str(one / log.parent.relative_to(archive)), "--no-html",
                        "--no-db", "--quiet"])
        codes[log.name] = rc
    assert codes["not-a-log.mcap"] == 2 and sorted(codes.values()).count(2) == 1
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["solve", "--archive", str(archive), "--out", str(tmp_path / "dask"), "--workers", "2",
                              "--db", str(db)])
    assert rc == 4, stderr
    assert "6 log(s), 0 already solved" in stdout and "to solve on local (2 workers)" in stdout
    assert "solved 5 of 6 log(s)" in stdout
    failed = [line for line in stderr.splitlines() if " FAILED " in line]
    assert len(failed) == 1 and "not-a-log.mcap" in failed[0]
    assert results_below(tmp_path / "dask") == results_below(one) and len(results_below(one)) == 5
    with open_records(str(db)) as records:
        assert {r.serial for r in records.list_runs()} == {*SERIALS, "ARC-D"}
        assert len(records.list_runs(serial="ARC-A")) == 2
        assert all(r.results == 1 and r.log_path and r.started_utc for r in records.list_runs())
    rc, stdout, _ = cli(["db", "history", "--db", str(db), "ARC-A", "--coefficient", "Kg_x"])
    assert rc == 0 and "ARC-A: 2 calibration(s)" in stdout

    # resumable: what this version solved is skipped, the broken file is tried again
    rc, stdout, stderr = cli(["solve", "--archive", str(archive), "--out", str(tmp_path / "dask"),
                              "--scheduler", "loop", "--db", str(db)])
    assert rc == 4
    assert "6 log(s), 5 already solved" in stdout and "1 to solve on loop" in stdout
    assert "not-a-log.mcap" in stderr


@pytest.mark.slow
def test_the_plain_loop_writes_the_same_next_to_each_log(archive, tmp_path):
    copy = tmp_path / "copy"
    shutil.copytree(archive / "a", copy)
    rc, stdout, stderr = cli(["solve", "--archive", str(copy), "--scheduler", "loop", "--no-db", "--quiet"])
    assert rc == 0, stderr
    for log in copy.rglob("*.mcap"):
        rc, _, _ = cli(["solve", str(log), "--out", str(tmp_path / "ref" / log.parent.relative_to(copy)), "--no-html",
                        "--no-db", "--quiet"])
    assert results_below(copy) == results_below(tmp_path / "ref") and len(results_below(copy)) == 2


@pytest.mark.slow
def test_archive_usage_errors(archive, tmp_path):
    log = next(archive.rglob("*.mcap"))
    for argv, message in (([str(log), "--archive", str(archive)], "not both"),
                          (["--archive", str(tmp_path / "none")], "no such folder"),
                          (["--archive", str(tmp_path)], "no run log"),
                          (["--archive", str(archive), "--compare", "optimal,all"], "drop --compare"),
                          (["--archive", str(archive), "--workers", "0"], "needs at least 1"),
                          (["--archive", str(archive), "--scheduler", "udp://x", "--no-db"], "say local, loop or"),
                          ([], "give run log(s), or --archive")):
        rc, _, stderr = cli(["solve", *argv])
        assert rc == 2 and message in stderr, (argv, stderr)


@pytest.mark.slow
def test_a_resumed_runs_logs_are_one_calibration_in_the_archive(tmp_path):
    """A run killed and resumed leaves two logs next to each other, the later naming the earlier: the archive
    solves them together, as `bench solve LATER` does, and not the earlier alone (an extra, partial calibration
    in the unit's history)."""
    from bench.jobs.archive import find_logs, resumed_parts
    from tests.helpers.run import kill_run_after_units, load_json

    run = tmp_path / "archive" / "resumed"
    run.mkdir(parents=True)
    config = tmp_path / "bench.toml"
    config.write_text(config_text(dwell_s=1.0, rate_hz=20.0), encoding="utf-8")
    killed, _ = kill_run_after_units(config, run)
    rc, _, stderr = cli(["run", "--config", str(config), "--out", str(run), "--quiet", "--no-db", "--resume",
                         str(killed)])
    assert rc == 0, stderr
    resumed = next(p for p in run.glob("*.mcap") if p != killed)
    for stray in run.glob("*.result.json"):     # the archive writes its own results
        stray.unlink()
    assert resumed_parts(find_logs([tmp_path / "archive"])) == {killed.absolute(): resumed.absolute()}

    rc, out, err = cli(["solve", "--archive", str(tmp_path / "archive"), "--scheduler", "loop", "--no-db",
                        "--out", str(tmp_path / "solved")])
    assert rc == 0, err
    assert f"{killed.absolute()}: an earlier log of a resumed run, solved with {resumed.name}" in out
    results = results_below(tmp_path / "solved")
    assert len(results) == 1, sorted(results)
    rc, _, err = cli(["solve", str(resumed), "--out", str(tmp_path / "one"), "--no-html", "--no-db"])
    assert rc == 0, err
    alone = load_json(next((tmp_path / "one").glob("*.solved.result.json")))
    archived = load_json(next((tmp_path / "solved").rglob("*.solved.result.json")))
    assert archived["coefficients"] == alone["coefficients"]
    assert archived["run"]["logs"] == alone["run"]["logs"] == [killed.name, resumed.name]


READER_POOLS = ("mcap-inflate", "can-stream", "can-frames")


@pytest.mark.slow
def test_an_archive_task_is_one_cores_work(archive, tmp_path, monkeypatch):
    """An archive task's log reader starts no thread pool: the cores are the workers', one task each (with pools
    of its own each solve took 1.2 cores and two workers on two cores competed for them). The same log solved as
    `bench solve LOG` does uses the reader's pools (on a machine of 4 cores: so this check can fail)."""
    from concurrent.futures import ThreadPoolExecutor as Pool

    from bench.jobs.archive import solve_log
    from bench.log import threads

    monkeypatch.setattr(threads, "usable_cores", lambda: 4)
    made: list[str] = []
    original = Pool.__init__

    def spy(self, max_workers=None, thread_name_prefix="", *args, **kwargs):
        made.append(thread_name_prefix)
        original(self, max_workers, thread_name_prefix, *args, **kwargs)

    monkeypatch.setattr(Pool, "__init__", spy)
    log = next((archive / "a" / "1").glob("*.mcap"))
    rc, _, stderr = cli(["solve", str(log), "--out", str(tmp_path / "one"), "--no-html", "--no-db", "--quiet"])
    assert rc == 0, stderr
    assert {name for name in made if name in READER_POOLS}, made
    made.clear()
    item = solve_log(str(log), str(tmp_path / "task"))
    assert item.ok, item.error
    assert not [name for name in made if name in READER_POOLS], made
    assert results_below(tmp_path / "task") == results_below(tmp_path / "one")


@pytest.mark.slow
def test_a_thermal_runs_log_is_re_solved_one_calibration_per_temperature(thermal_run_log, tmp_path):
    """A thermal run's log in the archive is solved as `bench solve LOG` solves it: one calibration per
    temperature and the thermal model refitted (solved whole, its two temperatures made one calibration that
    failed the residual test)."""
    from bench.model.result import CalibrationResult
    from bench.thermal.model import ThermalModel
    from tests.helpers.run import only_file

    (tmp_path / "archive" / "thermal").mkdir(parents=True)
    log = Path(shutil.copy(thermal_run_log, tmp_path / "archive" / "thermal"))
    rc, _, stderr = cli(["solve", str(log), "--out", str(tmp_path / "one"), "--no-html", "--no-db", "--quiet"])
    assert rc == 0, stderr
    db = tmp_path / "r.sqlite"
    rc, out, stderr = cli(["solve", "--archive", str(tmp_path / "archive"), "--scheduler", "loop", "--db", str(db),
                           "--out", str(tmp_path / "solved")])
    assert rc == 0, stderr
    solved = tmp_path / "solved" / "thermal"
    assert results_below(solved) == results_below(tmp_path / "one")
    assert len(results_below(solved)) == 3           # T1, T2 and the headline block
    model, alone = (ThermalModel.load(only_file(d, "*.thermal.json")) for d in (solved, tmp_path / "one"))
    assert len(model.points) == 2 and model.model_json() == alone.model_json()
    assert CalibrationResult.load(only_file(solved, "*.solved.result.json")).run.extra["thermal"]["this_block"]
    with open_records(str(db)) as records:
        assert [r.serial for r in records.list_runs()] == ["THERMAL-1"]


# -- issue 27: the archive's skip follows the log's content, copies are named, nothing goes unrecorded silently ----

@pytest.mark.slow
def test_moved_logs_are_skipped_by_run_id_and_content_and_a_backup_copy_gets_its_own_outputs(archive, tmp_path):
    """Keyed on the log's path, every call after the logs moved re-solved everything and added result rows (three
    for one run after two calls); two logs of one run in one folder wrote one output file ("solved 4 of 5", three
    result files)."""
    first = tmp_path / "first"
    shutil.copytree(archive / "b", first)
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["solve", "--archive", str(first), "--scheduler", "loop", "--db", str(db),
                              "--out", str(tmp_path / "out1")])
    assert rc == 0, stderr
    moved = tmp_path / "moved" / "elsewhere"
    shutil.move(str(first), moved)
    rc, stdout, stderr = cli(["solve", "--archive", str(moved), "--scheduler", "loop", "--db", str(db),
                              "--out", str(tmp_path / "out2")])
    assert rc == 0, stderr
    assert "1 log(s), 1 already solved" in stdout and "0 to solve" in stdout
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        assert run.results == 1

    (log,) = moved.glob("*.mcap")
    backup = moved / f"{log.stem}.backup.mcap"
    shutil.copy(log, backup)
    rc, stdout, stderr = cli(["solve", "--archive", str(moved), "--scheduler", "loop", "--db", str(db), "--redo",
                              "--out", str(tmp_path / "out3")])
    assert rc == 0, stderr
    assert f"{backup}, {log}: 2 logs of one run" in stdout or f"{log}, {backup}: 2 logs of one run" in stdout
    assert "solved 2 of 2 log(s)" in stdout
    results = results_below(tmp_path / "out3")
    assert sorted(Path(p).parent.name for p in results) == sorted([log.stem, backup.stem]), sorted(results)


@pytest.mark.slow
def test_every_result_not_recorded_is_a_non_zero_exit_and_relative_out_is_resolved(archive, tmp_path, monkeypatch):
    """`--out RELATIVE` on a Dask cluster wrote into the worker's folder and recorded nothing, exit 0."""
    import bench.jobs.archive as archive_module

    folder = tmp_path / "c"
    shutil.copytree(archive / "c", folder)
    seen: list[tuple[Path, Path]] = []
    real = archive_module.solve_archive

    def spy(tasks, **kwargs):
        seen.extend(tasks)
        return real(tasks, **kwargs)

    monkeypatch.setattr(archive_module, "solve_archive", spy)
    monkeypatch.chdir(tmp_path)
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    rc, stdout, stderr = cli(["solve", "--archive", "c", "--scheduler", "loop", "--db", str(blocker / "r.sqlite"),
                              "--out", "relative"])
    assert rc == 4, stderr
    assert "NOT recorded" in stderr and "1 result(s) not recorded" in stderr
    assert seen and all(out.is_absolute() and log.is_absolute() for log, out in seen)
    assert results_below(tmp_path / "relative")


@pytest.mark.slow
def test_a_log_starting_before_year_1_in_utc_does_not_stop_the_archive(archive, tmp_path):
    """Issue 34: `run.started_utc = 0001-01-01T00:00:00+05:00` crashed the recording of its result (OverflowError)
    and stopped `bench solve --archive`: the logs after it were never solved."""
    from mcap.reader import make_reader

    from tests.helpers.crafted import rewrite_log

    (log,) = (archive / "c").glob("*.mcap")
    with open(log, "rb") as f:
        run = next(dict(r.metadata) for r in make_reader(f).iter_metadata() if r.name == "run")
    folder = tmp_path / "arch"
    folder.mkdir()
    rewrite_log(log, folder / "a-early.mcap", metadata={"run": {**run, "started_utc": "0001-01-01T00:00:00+05:00",
                                                                "run_id": "early-run"}})
    for other in ("a", "b"):
        shutil.copy(next((archive / other).rglob("*.mcap")), folder / f"z-{other}.mcap")
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["solve", "--archive", str(folder), "--scheduler", "loop", "--db", str(db),
                              "--out", str(tmp_path / "out")])
    # every log solved; the hostile date is named as the log's damage, a failed quality check of that result
    assert rc == 4 and "1 log(s) failed or failed a quality check" in stderr, stderr
    assert "solved 3 of 3 log(s)" in stdout and "is not a date and time in UTC" in stdout
    with open_records(str(db)) as records:
        runs = {r.run_id: r for r in records.list_runs()}
    assert len(runs) == 3 and runs["early-run"].started_utc is None and runs["early-run"].results == 1


@pytest.mark.slow
def test_a_thermal_runs_folder_imports_with_its_headline_result_as_the_record(thermal_run_log, tmp_path):
    """`bench db import` of a thermal run's folder: its headline result (the block nearest the model's reference
    temperature, named after the run) is the run's record of truth; each temperature's result is recorded as a
    block of it, and the thermal model is said to hold nothing to record (issue 27)."""
    folder = tmp_path / "run"
    shutil.copytree(thermal_run_log.parent, folder)
    db = tmp_path / "r.sqlite"
    rc, stdout, stderr = cli(["db", "import", "--db", str(db), str(folder)])
    assert rc == 0, stderr
    assert "with nothing to record" in stdout and ".thermal.json: a thermal model" in stdout
    with open_records(str(db)) as records:
        (run,) = records.list_runs()
        rows = records.results_of(run.run_id)
    (truth,) = [r for r in rows if r.truth]
    assert truth.origin == "run" and Path(truth.path).name == f"{run.run_id}.result.json"
    assert sorted(r.origin for r in rows if not r.truth) == ["block", "block"]
