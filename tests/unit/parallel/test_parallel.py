"""`bench.parallel` (issue 20): Monte-Carlo work on Dask gives what the plain loop gives, to the last bit.

One Dask cluster of two single-threaded workers serves the module, reached by address over TCP on
127.0.0.1 (`--scheduler tcp://...`, as a lab's scheduler is reached: every task and result is
serialised and sent); its workers are threads of the test process, which spares the suite a
worker process's imports (seconds each). Worker processes are tested by the `local` path
(a cluster started by the command): `bench solve --archive --workers 2` in
tests/unit/solve/test_archive.py.
"""

from __future__ import annotations

import sys

import pytest

from bench.cli.recommend import format_recommendation
from bench.model.imu import NoiseModel
from bench.parallel import SchedulerError, run_tasks
from bench.schedule_design.monte_carlo import builtin_schedules, chunk_sizes, evaluate
from bench.schedule_design.recommend import PointingLevel, recommend
from schedules import load_builtin
from tests.helpers.run import cli

distributed = pytest.importorskip("distributed", reason="dask[distributed] (the archive extra) is not installed")


@pytest.fixture(scope="module")
def scheduler():
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=False, protocol="tcp://",
                                       dashboard_address=None, host="127.0.0.1", silence_logs=40)
    try:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        yield cluster.scheduler_address
    finally:
        cluster.close()


def _pure(k: int) -> int:
    if k == 3:
        raise ValueError("three is bad")
    return k * k


def test_tasks_run_on_the_cluster_and_a_failed_task_is_handed_back_not_raised(scheduler):
    for where in ("loop", scheduler):
        got = {index: (result, None if error is None else str(error))
               for index, result, error in run_tasks(_pure, ((k,) for k in range(6)), scheduler=where)}
        assert got == {0: (0, None), 1: (1, None), 2: (4, None), 3: (None, "three is bad"), 4: (16, None),
                       5: (25, None)}, where


def test_evaluate_on_dask_is_the_plain_loop_to_the_last_bit(scheduler):
    positions, rotations = builtin_schedules()
    # 11 runs in chunks of 3: four tasks, the last one short, spread over two worker processes
    assert chunk_sizes(11, 3) == [3, 3, 3, 2]
    serial = evaluate(positions, rotations, runs=11, seed=5, chunk_runs=3)
    done = []
    on_dask = evaluate(positions, rotations, runs=11, seed=5, chunk_runs=3, scheduler=scheduler,
                       progress=lambda k, n: done.append((k, n)))
    assert on_dask == serial
    assert done == [(1, 4), (2, 4), (3, 4), (4, 4)]
    # one chunk of all 11 runs: the same draws, the same numbers but for the order of one sum
    whole = evaluate(positions, rotations, runs=11, seed=5)
    for name in ("positions", "rotations"):
        for a, b in zip(whole[name], serial[name]):
            assert a.keys() == b.keys()
            assert all(a[k] == pytest.approx(b[k], rel=1e-13) for k in a if k != "method")


def test_recommend_on_dask_is_the_plain_loop(scheduler):
    kw = dict(positions=[load_builtin("optimal-24"), load_builtin("traditional-12")],
              rotations=[load_builtin("optimal-5s6r"), load_builtin("traditional-3s6r")], runs=6, seed=2,
              revolutions_grid=(1, 2), dwell_grid_s=(10.0, 30.0))
    serial = recommend(20000.0, PointingLevel.uniform(60.0), NoiseModel(), **kw)
    on_dask = recommend(20000.0, PointingLevel.uniform(60.0), NoiseModel(), scheduler=scheduler, **kw)

    def rows(rec):
        return [(c.pair, c.dwell_s, c.revolutions, c.duration_s, c.score, c.errors) for c in rec.ranked]
    assert rows(on_dask) == rows(serial) and len(rows(serial)) == 16


@pytest.mark.slow
def test_the_commands_take_a_scheduler_by_address(scheduler, tmp_path):
    out = {}
    for where in ("loop", scheduler):
        rc, stdout, stderr = cli(["evaluate", "--runs", "5", "--seed", "3", "--scheduler", where,
                                  "--json", str(tmp_path / "t.json")])
        assert rc == 0, stderr
        out[where] = (tmp_path / "t.json").read_text()
        assert f"on {where}" in stdout
    assert out["loop"] == out[scheduler]
    # the same on the cluster as in the library on the loop (test_recommend_on_dask_is_the_plain_loop)
    rc, stdout, stderr = cli(["schedules", "recommend", "--budget-s", "2500", "--pointing-arcsec", "40",
                              "--runs", "4", "--top", "3", "--scheduler", scheduler])
    assert rc == 0, stderr
    expected = format_recommendation(recommend(2500.0, PointingLevel.uniform(40.0), NoiseModel(), runs=4), 3)
    assert stdout.splitlines() == expected


@pytest.mark.parametrize("argv, message", [
    (["evaluate", "--scheduler", "udp://x"], "say local, loop or tcp://HOST:PORT"),
    (["evaluate", "--scheduler", "local", "--workers", "0"], "--workers 0: needs at least 1"),
    (["schedules", "recommend", "--budget-s", "4000", "--pointing-arcsec", "40", "--scheduler", "nowhere"],
     "say local, loop or"),
    (["evaluate", "--runs", "3", "--scheduler", "tcp://127.0.0.1:9"], "cannot reach the Dask scheduler"),
])
def test_bad_schedulers_are_one_line_usage_errors(argv, message, monkeypatch):
    monkeypatch.setattr("bench.parallel.CONNECT_TIMEOUT_S", 1.0)     # nothing listens on port 9: no need to wait
    rc, stdout, stderr = cli(argv)
    assert rc == 2 and message in stderr and len(stderr.strip().splitlines()) == 1, stderr


def test_without_dask_installed_one_line_says_how_to_get_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "distributed", None)     # `import distributed` raises ImportError
    with pytest.raises(SchedulerError, match=r"needs dask\[distributed\]: pip install -e '.\[archive\]'"):
        list(run_tasks(_pure, [(1,)], scheduler="local"))
    rc, _, stderr = cli(["evaluate", "--runs", "3", "--scheduler", "local"])
    assert rc == 2 and "pip install -e '.[archive]'" in stderr


def _malloc_trim_threshold() -> str | None:
    import os
    return os.environ.get("MALLOC_TRIM_THRESHOLD_")


@pytest.mark.slow
def test_local_workers_keep_the_dynamic_mmap_threshold(monkeypatch):
    """Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which made a log's solve take 1.6x the CPU
    in a worker (every large numpy temporary mmapped and page-faulted afresh): our local workers go without."""
    monkeypatch.delenv("MALLOC_TRIM_THRESHOLD_", raising=False)     # what the workers inherit from us
    [(index, value, error)] = list(run_tasks(_malloc_trim_threshold, [()], scheduler="local", workers=1))
    assert error is None and value is None


@pytest.mark.slow
def test_a_local_cluster_does_not_need_the_dashboard_port():
    """With 127.0.0.1:8787 (Dask's default HTTP port) held, by another cluster or a second archive solved at once,
    the local cluster runs its tasks without Dask's multi-line "Port 8787 is already in use" warning (its HTTP
    endpoints listen on a free loopback port)."""
    import socket
    import warnings

    holder = socket.socket()
    try:
        holder.bind(("127.0.0.1", 8787))
        holder.listen()
    except OSError:     # held already: the case this test makes
        pass
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            assert list(run_tasks(abs, [(-1,)], scheduler="local", workers=1)) == [(0, 1, None)]
    finally:
        holder.close()
    assert not [w for w in caught if "already in use" in str(w.message)], [str(w.message) for w in caught]
