"""Fixtures shared by test files: the leftover-thread check runs for every test (autouse); the recorded logs that
tests only read are recorded once per session (`short_run`, `cli_run_log`, `thermal_run_log`; tests/unit/conftest.py
has `noisy_run`).

A shared recording is read only: a test that needs to change a file copies it to its `tmp_path` first, and writes
its own outputs (`--out`) there. `shared_recordings_unchanged` fails the test that writes into one
(tests/helpers/shared.py)."""

from __future__ import annotations

import os
import signal
from pathlib import Path
from types import SimpleNamespace

import pytest

# assertion introspection in the shared helpers too (registered before any of them is imported)
pytest.register_assert_rewrite("tests.helpers")

from tests.helpers.shared import changed_shared, recorded_once, share  # noqa: E402
from tests.helpers.threads import check_no_leftover_threads, project_threads  # noqa: E402

E2E = Path(__file__).parent / "e2e"
#: session fixtures whose recording takes minutes: their tests run on one pytest-xdist worker (one group)
LONG_SESSION_RECORDINGS = ("documented_thermal_run",)


def pytest_configure(config):
    """A suite started under `nohup` inherits an ignored SIGHUP, and so would every bench process it starts: the
    bench keeps an ignored SIGHUP ignored on purpose (`nohup bench run`), so the tests that hang up on one would
    fail. A handler of our own instead of the ignore: pytest still survives a hangup, and the processes it
    starts get the default back (exec resets a caught signal, not an ignored one)."""
    if hasattr(signal, "SIGHUP") and signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
        signal.signal(signal.SIGHUP, lambda signum, frame: None)


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config) -> int | None:
    """`-n auto` (pyproject's addopts) starts one worker per CPU this process may run on, so `taskset -c 0 pytest`
    runs one. (xdist's own count asks psutil for the machine's physical cores, which ignores the affinity.)
    PYTEST_XDIST_AUTO_NUM_WORKERS still wins."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    return len(os.sched_getaffinity(0))


def _module_scoped_fixtures(item) -> bool:
    """Whether the test uses a fixture made once per module or class. Read from pytest's fixture info of the item,
    which has no public name; without it every test counts as using one (a module's tests then stay together)."""
    info = getattr(item, "_fixtureinfo", None)
    if info is None:
        return True
    return any(definition.scope in ("module", "class", "package")
               for definitions in info.name2fixturedefs.values() for definition in definitions)


@pytest.hookimpl(tryfirst=True)    # before xdist's own, which turns the groups into the tests' ids in each worker
def pytest_collection_modifyitems(config, items):
    """Every test in tests/e2e/ (whole simulated runs) is `slow`, without a mark in each module.

    Under pytest-xdist (`--dist loadgroup`, pyproject's addopts) the tests of a module that share a module- or
    class-scoped fixture (a recorded run, a server) are one group, run by one worker, so that the fixture is made
    once; every other test goes to whichever worker is free. Session fixtures are shared across workers by
    `tests.helpers.shared.recorded_once`; the tests of one that takes minutes (`LONG_SESSION_RECORDINGS`) are one
    group too, so that no other worker waits for it. A test marked with a group keeps it."""
    for item in items:
        if E2E in item.path.parents:
            item.add_marker(pytest.mark.slow)
        if item.get_closest_marker("xdist_group") is not None:
            continue
        long_recording = next((name for name in LONG_SESSION_RECORDINGS if name in item.fixturenames), None)
        if long_recording is not None:
            item.add_marker(pytest.mark.xdist_group(long_recording))
        elif _module_scoped_fixtures(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::", 1)[0]))


@pytest.fixture(autouse=True)
def no_leftover_project_threads():
    """Fails the test if a project thread (tests/helpers/threads.py) started during it is still
    running 5 s after it. Threads alive before the test (e.g. started by a module-scoped fixture)
    are not blamed on it; being autouse and function-scoped, this runs its check after the test's
    other function-scoped fixtures are torn down."""
    before = project_threads()
    yield
    failure = None
    try:
        check_no_leftover_threads(before)
    except AssertionError as e:
        failure = str(e)
    if failure is not None:
        pytest.fail(failure, pytrace=False)


@pytest.fixture(autouse=True)
def shared_recordings_unchanged():
    """Fails the test that added, removed or rewrote a file in a shared recording's folder (`share`)."""
    yield
    changed = changed_shared()
    if changed:
        pytest.fail("a test wrote into a shared recording (copy it to tmp_path first): " + "; ".join(changed),
                    pytrace=False)


@pytest.fixture
def no_leftover_tui_threads(no_leftover_project_threads):
    """Former opt-in name of the check, kept as an alias: every test is checked anyway."""
    yield


@pytest.fixture(scope="session", autouse=True)
def records_database_of_the_session(tmp_path_factory):
    """A records database for what runs outside a test's own (module and session fixtures that record a run):
    never the user's default one, whose schema may be another version's (a module fixture once failed with
    "the database has schema version 4, newer than this software's 3" from a developer's other checkout)."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("BENCH_DB", str(tmp_path_factory.mktemp("session-records") / "records.sqlite"))
        yield


@pytest.fixture(autouse=True)
def records_database_in_tmp(tmp_path_factory, monkeypatch):
    """Every test's `bench run` / `bench solve` / `bench check-table` records into a database of its own in a
    temporary folder, never into the user's default one (`bench.records.store.default_url`)."""
    monkeypatch.setenv("BENCH_DB", str(tmp_path_factory.mktemp("records") / "records.sqlite"))


@pytest.fixture(scope="session")
def thermal_run_log(tmp_path_factory):
    """The log of `bench run --sim` of the shortest thermal plan (`tests.helpers.run.record_thermal_run`, serial
    "THERMAL-1"), shared by the tests that read, replay or re-solve one (copy it to change it)."""
    from tests.helpers.run import record_thermal_run

    def record(folder: Path) -> str:
        return str(record_thermal_run(folder / "run", serial="THERMAL-1").relative_to(folder))

    folder, log = recorded_once(tmp_path_factory, "thermal-run", record)
    share(folder)
    return folder / log


@pytest.fixture(scope="session")
def short_run(tmp_path_factory) -> SimpleNamespace:
    """A finished simulated run of the shortest plan (`tests.helpers.run.record_short_run`: traditional-12 +
    traditional-3s6r, 1 s dwells), recorded once per session for the tests that only read it: `log` (the MCAP),
    `result` (its result file), `finished_s` (the run clock's time when it finished). Copy a file to change it."""
    from tests.helpers.run import record_short_run

    def record(folder: Path) -> dict:
        with pytest.MonkeyPatch.context() as patch:   # a database of its own, as every test has
            patch.setenv("BENCH_DB", str(tmp_path_factory.mktemp("short-run-records") / "records.sqlite"))
            log, finished_s = record_short_run(folder)
        return {"log": str(Path(log).relative_to(folder)), "finished_s": finished_s}

    folder, recorded = recorded_once(tmp_path_factory, "short-run", record)
    share(folder)
    log = folder / recorded["log"]
    return SimpleNamespace(log=log, result=next(log.parent.glob("*.result.json")), finished_s=recorded["finished_s"])


@pytest.fixture(scope="session")
def cli_run_log(tmp_path_factory) -> Path:
    """The log of `bench run --config` of the short test plan with 1 s dwells (`tests.helpers.run.config_text`;
    its configuration attached as bench.toml), recorded once per session for the tests that only read it."""
    from tests.helpers.run import cli, config_text, only_file

    def record(folder: Path) -> None:
        config = folder / "bench.toml"
        config.write_text(config_text(dwell_s=1.0), encoding="utf-8")
        rc, _, stderr = cli(["run", "--config", str(config), "--out", str(folder / "run"), "--quiet", "--no-db"])
        assert rc == 0, stderr

    folder, _ = recorded_once(tmp_path_factory, "cli-run", record)
    share(folder)
    return only_file(folder / "run", "*.mcap")


@pytest.fixture(scope="session")
def documented_thermal_run(tmp_path_factory) -> SimpleNamespace:
    """docs/how-to/thermal.md's chamber-driven run (`tests.helpers.docs_shell.THERMAL_RUN_COMMAND`: the shipped
    thermal.example.toml, four temperatures, minutes of CPU) run as the page's test runs it, in bash in a folder
    holding the examples, once per session: `cwd` (that folder), `out` (the run's folder) and `stdout` (paths in it
relative to `cwd`, as given). Shared by the page's test
    (tests/architecture/test_docs.py) and tests/e2e/test_thermal_chamber_run.py, which checks what it wrote."""
    from tests.helpers.docs_shell import THERMAL_RUN_COMMAND, run_bench_shell, with_examples

    def record(folder: Path) -> str:
        done = run_bench_shell(THERMAL_RUN_COMMAND, with_examples(folder))
        assert done.returncode == 0, f"exit {done.returncode}\n{done.stdout[-2000:]}\n{done.stderr[-2000:]}"
        return done.stdout

    folder, stdout = recorded_once(tmp_path_factory, "documented-thermal-run", record)
    share(folder)
    return SimpleNamespace(cwd=folder, out=folder / "runs" / "thermal-run", stdout=stdout)
