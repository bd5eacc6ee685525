"""Re-solve an archive of run logs, each log as `bench solve LOG` would, in parallel on Dask distributed.

`find_logs(folders)` lists every `*.mcap` below the folders; `resumed_parts(logs)` finds the
logs a resumed run's later log names as its earlier ones (solved with it, not on their own:
an interrupted run is one calibration); `solve_log(log, out_dir)` is
one task: read, solve, write `<stem>.result.json` and the report exactly as `bench solve`
does (`bench.finish`, `bench.jobs.resolve`), and return an `ArchiveItem` (a log that cannot be solved
is an item with its reason, never an exception: one bad log does not stop the archive).
`solve_archive` runs the tasks with `bench.parallel.run_tasks` on a Dask cluster (a
`LocalCluster` of `workers` processes, or a running scheduler by address) or, with
`scheduler="loop"`, one by one in this process (the reference the Dask overhead is measured
against), and hands each item to `on_done` as it completes, in completion order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable

from bench.errors import BenchError
from bench.finish.finish import finish
from bench.finish.recorded import load_recorded
from bench.jobs.resolve import ResolveTarget, output_stem
from bench.log.names import logs_before, safe_name, sibling_log
from bench.log.reader import read_log
from bench.log.threads import reader_threads_limited
from bench.parallel import SchedulerError, run_tasks
from bench.solve.methods import SolverError

#: The archive cannot be solved at all: a bad scheduler, Dask missing, a scheduler that cannot be reached.
ArchiveError = SchedulerError


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


def resumed_parts(logs: list[Path]) -> dict[Path, Path]:
    """{earlier log: the later log naming it in `run.logs_before`} among `logs`: a resumed run's logs, which
    `bench solve LATER` solves together (each alone would be an extra, partial calibration in the unit's history).
    A log's earlier logs lie next to it (`sibling_log`), so only the logs of folders holding more than one are
    read (their metadata only); a log that cannot be read names nothing (its own solve reports it)."""
    folders: dict[Path, set[Path]] = {}
    for log in logs:
        folders.setdefault(log.parent, set()).add(log)
    parts: dict[Path, Path] = {}
    for group in folders.values():
        for log in sorted(group) if len(group) > 1 else ():
            try:
                entries, _ = logs_before(read_log(str(log), messages=False).metadata)
            except (BenchError, OSError):
                continue
            for entry in entries:
                earlier, _ = sibling_log(log, entry)
                if earlier is not None and earlier in group:
                    parts.setdefault(earlier, log)
    return parts


def log_run_ids(logs: list[Path]) -> dict[Path, str]:
    """{log: its run id} for the logs whose metadata can be read (the others are left out: their solve says why)."""
    ids: dict[Path, str] = {}
    for log in logs:
        try:
            run = read_log(str(log), messages=False).metadata.get("run") or {}
        except (BenchError, OSError):
            continue
        run_id = str(run.get("run_id", "")).strip()
        if run_id:
            ids[log] = run_id
    return ids


def same_run_logs(tasks: list[tuple[Path, Path]]) -> list[list[Path]]:
    """Groups of two or more logs of one run that would write the same outputs (same output folder, same run id:
    a backup copy next to the log is common). Only the logs sharing an output folder are read (metadata only)."""
    by_folder: dict[Path, list[Path]] = {}
    for log, out_dir in tasks:
        by_folder.setdefault(out_dir, []).append(log)
    groups: list[list[Path]] = []
    for folder_logs in by_folder.values():
        if len(folder_logs) < 2:
            continue
        by_run: dict[str, list[Path]] = {}
        for log, run_id in log_run_ids(folder_logs).items():
            by_run.setdefault(run_id, []).append(log)
        groups += [sorted(group) for group in by_run.values() if len(group) > 1]
    return groups


def distinct_outputs(tasks: list[tuple[Path, Path]], groups: list[list[Path]]) -> list[tuple[Path, Path]]:
    """The tasks with each log of a group in `same_run_logs` solved into a folder of its own, named after the log
    (`OUT/<log stem>/`), so no result overwrites another's."""
    own = {log: k for group in groups for k, log in enumerate(group, 1)}
    return [(log, out_dir / (safe_name(log.stem) or f"copy-{own[log]}") if log in own else out_dir)
            for log, out_dir in tasks]


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
    log. One core's work: the reader spawns no threads (the archive's parallelism is its workers', one task
    each; threads of its own would take cores from the other workers for a few per cent of this task's time)."""
    with reader_threads_limited(1):
        return _solve_log(log, out_dir, html)


def _solve_log(log: str, out_dir: str, html: bool) -> ArchiveItem:
    try:
        recorded = load_recorded([log])
        finished = finish(recorded, ResolveTarget(Path(out_dir), output_stem(recorded), html=html))
    except SolverError as exc:
        return ArchiveItem(log, False, error=f"cannot be solved: {exc}")
    except BenchError as exc:       # (a static noise recording is refused, as `bench solve LOG` refuses it)
        return ArchiveItem(log, False, error=str(exc))
    except OSError as exc:
        return ArchiveItem(log, False, error=f"{exc.strerror or exc} ({exc.filename})")
    failures = finished.failures
    if finished.verdict is not None:
        failures = [c.describe() for c in finished.verdict.failed]
    return ArchiveItem(log, True, result=str(finished.result_path), run_id=recorded.run_id, failures=tuple(failures))


def solve_archive(tasks: list[tuple[Path, Path]], *, scheduler: str = "local", workers: int | None = None,
                  html: bool = False, on_done: Callable[[ArchiveItem], None] | None = None) -> list[ArchiveItem]:
    """Solve every (log, out_dir) on `scheduler` (`bench.parallel.run_tasks`: "local", "tcp://HOST:PORT" or
    "loop"); a task that fails (a worker that died, a bug) fails its log only."""
    items: list[ArchiveItem] = []
    calls = [(str(log), str(out_dir), html) for log, out_dir in tasks]
    for index, item, error in run_tasks(solve_log, calls, scheduler=scheduler, workers=workers):
        if error is not None:
            item = ArchiveItem(str(tasks[index][0]), False, error=f"{type(error).__name__}: {error}")
        items.append(item)
        if on_done is not None:
            on_done(item)
    return items


__all__ = ["ArchiveError", "ArchiveItem", "distinct_outputs", "find_logs", "log_run_ids", "output_folder",
           "resumed_parts", "same_run_logs", "solve_archive", "solve_log"]
