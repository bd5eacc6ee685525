"""Re-solve an archive of run logs, each log as `bench solve LOG` would, in parallel on Dask distributed.

`find_logs(folders)` lists every `*.mcap` below the folders; `solve_log(log, out_dir)` is
one task: read, solve, write `<stem>.result.json` and the report exactly as `bench solve`
does (`bench.solve.resolve`), and return an `ArchiveItem` (a log that cannot be solved
is an item with its reason, never an exception: one bad log does not stop the archive).
`solve_archive` runs the tasks on a Dask cluster (a `LocalCluster` of `workers` processes,
or a running scheduler by address) or, with `scheduler="loop"`, one by one in this
process (the reference the Dask overhead is measured against), and hands each item to
`on_done` as it completes, in completion order.

Dask is optional (the `archive` extra): it is imported only when an archive is solved on it.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from bench.errors import BenchError, InputError
from bench.solve.methods import SolverError
from bench.solve.resolve import load_recorded, solve_recorded, write_outputs


class ArchiveError(InputError):
    """The archive cannot be solved at all: Dask missing, a scheduler that cannot be reached."""


@dataclass(frozen=True)
class ArchiveItem:
    """What became of one log: solved (result path, quality failures) or not (the reason)."""

    log: str
    ok: bool
    result: str | None = None
    run_id: str | None = None
    error: str | None = None
    failures: tuple[str, ...] = ()


def find_logs(folders: Iterable[str | Path]) -> list[Path]:
    """Every `*.mcap` below the folders (a file named is taken as is), sorted, each once."""
    found: dict[Path, None] = {}
    for folder in map(Path, folders):
        paths = [folder] if folder.is_file() else sorted(p for p in folder.rglob("*.mcap") if p.is_file())
        for p in paths:
            found.setdefault(p.absolute(), None)
    return list(found)


def output_folder(log: Path, roots: list[Path], out: Path | None) -> Path:
    """Next to the log; under `out` at the log's place relative to its archive root (names never leave `out`)."""
    if out is None:
        return log.parent
    for root in roots:
        root = root.absolute()
        if log.is_relative_to(root) and root.is_dir():
            return out / log.parent.relative_to(root)
    return out


def solve_log(log: str, out_dir: str, html: bool = False) -> ArchiveItem:
    """One log, as `bench solve LOG --out OUT_DIR` (without `--no-html` when `html`) does; never raises for a bad
    log."""
    try:
        recorded = load_recorded([log])
        config = recorded.setup.config
        positions = config.plan.positions if config is not None else None
        if positions is not None and positions.kind == "static":     # as `bench solve LOG` refuses it
            return ArchiveItem(log, False, error=f"a static noise recording (plan positions {positions.name!r}), "
                                                 f"nothing to calibrate: analyse it with `bench noise {log}`")
        resolved = solve_recorded(recorded)
        result_path, _, _ = write_outputs(recorded, resolved, out_dir, html=html)
    except SolverError as exc:
        return ArchiveItem(log, False, error=f"cannot be solved: {exc}")
    except BenchError as exc:
        return ArchiveItem(log, False, error=str(exc))
    except OSError as exc:
        return ArchiveItem(log, False, error=f"{exc.strerror or exc} ({exc.filename})")
    failures = resolved.failures
    if resolved.verdict is not None:
        failures = [c.describe() for c in resolved.verdict.failed]
    return ArchiveItem(log, True, result=str(result_path), run_id=recorded.run_id, failures=tuple(failures))


def solve_archive(tasks: list[tuple[Path, Path]], *, scheduler: str = "local", workers: int | None = None,
                  html: bool = False, on_done: Callable[[ArchiveItem], None] | None = None) -> list[ArchiveItem]:
    """Solve every (log, out_dir); `scheduler`: "local" (a LocalCluster of `workers` processes, default the
    machine's cores), "tcp://HOST:PORT" (a running Dask scheduler) or "loop" (one by one here, no Dask)."""
    items: list[ArchiveItem] = []

    def done(item: ArchiveItem) -> None:
        items.append(item)
        if on_done is not None:
            on_done(item)

    if scheduler == "loop":
        for log, out_dir in tasks:
            done(solve_log(str(log), str(out_dir), html))
        return items
    try:
        # Dask is heavy and optional (the `archive` extra): imported only to solve an archive on it
        from distributed import Client, LocalCluster, as_completed
    except ImportError as exc:
        raise ArchiveError("solving an archive on Dask needs dask[distributed]: pip install -e '.[archive]' "
                           "(or --scheduler loop)") from exc
    cluster = None
    try:
        if scheduler == "local":
            # one single-threaded worker process per core: the solve is numpy/Python, a process each scales best
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                                   dashboard_address=None, host="127.0.0.1", silence_logs=40)
            client = Client(cluster)
        elif scheduler.startswith("tcp://"):
            client = Client(scheduler, timeout="10s")
        else:
            raise ArchiveError(f"--scheduler {scheduler!r}: say local, loop or tcp://HOST:PORT")
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        raise ArchiveError(f"cannot reach the Dask scheduler {scheduler}: {exc}") from exc
    try:
        futures = [client.submit(solve_log, str(log), str(out_dir), html, pure=False, key=f"solve-{k}")
                   for k, (log, out_dir) in enumerate(tasks)]
        by_key = {f.key: tasks[k][0] for k, f in enumerate(futures)}
        for future in as_completed(futures):
            try:
                done(future.result())
            except Exception as exc:    # noqa: BLE001  a worker that died or a bug in one task: that log fails, not all
                done(ArchiveItem(str(by_key[future.key]), False, error=f"{type(exc).__name__}: {exc}"))
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
    return items


__all__ = ["ArchiveError", "ArchiveItem", "find_logs", "output_folder", "solve_archive", "solve_log"]
