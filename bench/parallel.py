"""Independent tasks on Dask distributed or in a plain loop: one place for the cluster, the flow and the failures.

`run_tasks(func, calls, scheduler=..., workers=...)` calls `func(*args)` for every tuple of
`calls` and yields `(index, result, error)` as each task ends, `error` being the exception
the task raised (then `result` is None): the caller decides whether one failed task is
fatal (a Monte-Carlo sum) or only that item's (a log of an archive). `scheduler`:

- "loop": one by one in this process, in order, without Dask (the reference the cluster's
  overhead is measured against);
- "local": a Dask `LocalCluster` of `workers` single-threaded worker processes on 127.0.0.1
  (default: the machine's cores), started for the call and closed after it;
- "tcp://HOST:PORT": a running Dask scheduler (`dask scheduler`) and its workers, wherever they are.

`calls` is consumed lazily and at most a few tasks per worker are in flight, so a long
stream of tasks (Monte-Carlo chunks with their draws) is never all in memory at once.
A task must be a pure function of its arguments (no state kept on a worker, no global
random generator): where and in which order tasks run then cannot change any result.
Dask is optional (the `archive` extra) and imported only when a cluster is used.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator
from typing import Any

from bench.errors import InputError

SCHEDULERS = "local, loop or tcp://HOST:PORT"
#: tasks submitted ahead per worker thread: enough to keep every worker busy while results travel back
AHEAD_PER_THREAD = 2
#: how long to try to reach a scheduler by address before saying it cannot be reached
CONNECT_TIMEOUT_S = 10.0


class SchedulerError(InputError):
    """No way to run the tasks: a bad --scheduler, Dask not installed, a scheduler that cannot be reached."""


def check_scheduler(scheduler: str, workers: int | None = None) -> None:
    """Raise SchedulerError for a scheduler or worker count `run_tasks` cannot use (checked before any work)."""
    if scheduler not in ("local", "loop") and not scheduler.startswith("tcp://"):
        raise SchedulerError(f"--scheduler {scheduler!r}: say {SCHEDULERS}")
    if workers is not None and workers < 1:
        raise SchedulerError(f"--workers {workers}: needs at least 1")


def describe(scheduler: str, workers: int | None) -> str:
    """`local (2 workers)`, `loop`, `tcp://10.0.0.5:8786`: for progress lines."""
    return scheduler + (f" ({workers} workers)" if workers and scheduler == "local" else "")


def run_tasks(func: Callable[..., Any], calls: Iterable[tuple], *, scheduler: str = "local",
              workers: int | None = None) -> Iterator[tuple[int, Any, BaseException | None]]:
    """Yield `(index, func(*calls[index]), None)` or `(index, None, exception)` for every call as it ends."""
    check_scheduler(scheduler, workers)
    if scheduler == "loop":
        for index, args in enumerate(calls):
            try:
                result = func(*args)
            except Exception as exc:    # noqa: BLE001  handed to the caller, as a worker's failure is
                yield index, None, exc
            else:
                yield index, result, None
        return
    try:
        # Dask is heavy and optional (the `archive` extra): imported only to run tasks on it
        import dask
        from distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise SchedulerError("running on Dask needs dask[distributed]: pip install -e '.[archive]' "
                             "(or --scheduler loop)") from exc
    cluster = None
    try:
        if scheduler == "local":
            # one single-threaded worker process per core: the work is numpy/Python, a process each scales best
            # Dask starts its worker processes with MALLOC_TRIM_THRESHOLD_=65536, which turns off glibc's
            # dynamic mmap threshold: every array over 128 KiB is then mmapped and page-faulted afresh, and a
            # log's solve takes 1.6x the CPU (7x the page faults; measured, see README). Not for our workers.
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}):
                # no dashboard; the scheduler's HTTP endpoints (health, metrics) on a free loopback port, not on
                # 8787, which another cluster (or a second archive solved at once) may hold: Dask then warns
                cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                       processes=True, dashboard_address=None, host="127.0.0.1", silence_logs=40,
                                       scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
            client = Client(cluster)
        else:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT_S}s")
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise SchedulerError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from exc
    try:
        ahead = max(4, AHEAD_PER_THREAD * sum(client.nthreads().values()))
        pending = iter(enumerate(calls))
        index_of: dict[Any, int] = {}

        def submit() -> Any:
            nxt = next(pending, None)
            if nxt is None:
                return None
            index, args = nxt
            future = client.submit(func, *args, pure=False)    # a unique key: a shared scheduler has other users
            index_of[future.key] = index
            return future

        first = [f for f in (submit() for _ in range(ahead)) if f is not None]
        flow = as_completed(first)
        for future in flow:
            index = index_of.pop(future.key)
            try:
                result = future.result()
            except Exception as exc:    # noqa: BLE001  a task's error or a worker that died: the caller decides
                yield index, None, exc
            else:
                yield index, result, None
            finally:
                future.release()
            following = submit()
            if following is not None:
                flow.add(following)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


__all__ = ["SCHEDULERS", "SchedulerError", "check_scheduler", "describe", "run_tasks"]
