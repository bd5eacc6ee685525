"""Files on disk into the records database: result files (`*.result.json`), table-check results
(`*.table-check.json`), noise results (`*.noise.json`) and run logs (`*.mcap`), found in
folders or named one by one.

Idempotent: a result file already recorded (same SHA-256) is skipped, a run is keyed by its
run id. A result's run is described from the result and, when its log lies next to it,
from the log's metadata (start time, table, the log's hash). A file that cannot be read,
or holds what the records cannot take (`bench.records.content`), is reported in one line
and the rest go on. Files the bench writes that hold nothing the records keep (a thermal
model, `bench thermal sim`'s and `bench noise --sim`'s in-memory simulations) are named as
such (`NotRecorded`), not failures.
"""

from __future__ import annotations

import hashlib
import json
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from bench.errors import BenchError
from bench.records import content
from bench.records.content import IngestError, NotRecorded, read_json, regular_file
from bench.records.errors import RecordsError
from bench.records.store import Derivation, Records, RunInfo, utc

RESULT_FORMAT = "turntable-bench/result"
TABLE_CHECK_FORMAT = "turntable-bench/table-check"
NOISE_FORMAT = "turntable-bench/noise"
THERMAL_FORMAT = "turntable-bench/thermal"
#: the files `import_paths` takes from a folder
PATTERNS = ("*.result.json", "*.table-check.json", "*.noise.json", "*.thermal.json", "*.mcap")
_HASH_CHUNK = 1 << 20
#: the magic an MCAP file ends with after its footer: a file without it is still being written or was cut off
MCAP_MAGIC = b"\x89MCAP0\r\n"


@dataclass
class ImportReport:
    """What `import_paths` did: files newly recorded, already known, and failed (path, reason)."""

    added: list[str] = field(default_factory=list)
    known: list[str] = field(default_factory=list)
    failed: list[tuple[str, str]] = field(default_factory=list)
    not_recorded: list[tuple[str, str]] = field(default_factory=list)   # files of the bench with nothing to keep


def sha256_of(path: str | Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(_HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def mcap_finished(path: str | Path) -> bool:
    """The file ends with an MCAP footer's closing magic: its writer closed it (a run still recording, or killed,
    or a copy cut short, has none)."""
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        if size < 2 * len(MCAP_MAGIC):
            return False
        f.seek(size - len(MCAP_MAGIC))
        return f.read(len(MCAP_MAGIC)) == MCAP_MAGIC


def find_files(paths: list[str | Path]) -> list[Path]:
    """The files named, and in each folder named every file matching `PATTERNS` (recursively), sorted."""
    found: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            found += sorted({f for pattern in PATTERNS for f in p.rglob(pattern) if f.is_file()})
        else:
            found.append(p)
    return found


def _order(path: Path) -> int:
    """Results first, so that a log adds to its run; noise results last, their unit named by their run's log."""
    return 2 if path.name.endswith(".noise.json") else 1 if path.suffix == ".mcap" else 0


def import_paths(records: Records, paths: list[str | Path]) -> ImportReport:
    """Record every result file and log under `paths`; a file that fails is reported and the rest go on."""
    report = ImportReport()
    files = find_files(paths)
    for path in sorted(files, key=_order):
        try:
            new = import_file(records, path)
        except RecordsError:
            raise                               # the database failed: not this file's fault, stop
        except NotRecorded as exc:
            report.not_recorded.append((str(path), _reason(path, exc)))
            continue
        except (OSError, BenchError, ValueError, ArithmeticError, RecursionError, MemoryError) as exc:
            # the file is unreadable, damaged, hostile or not ours: the rest go on
            report.failed.append((str(path), _reason(path, exc)))
            continue
        (report.added if new else report.known).append(str(path))
    return report


def _reason(path: Path, exc: BaseException) -> str:
    """The one line of why, without the path the caller prints in front of it (a reader's message starts with it)."""
    if isinstance(exc, OSError) and exc.strerror:
        return exc.strerror
    if isinstance(exc, RecursionError):
        return "nested too deeply"
    reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
    for prefix in (f"{path}: ", f"{path.absolute()}: "):
        reason = reason.removeprefix(prefix)
    return reason[:300]


def import_file(records: Records, path: str | Path, log_sha256: str | None = None) -> bool:
    """Record one file; True if the database learnt something from it. `log_sha256`: the SHA-256 of the log a
    result was solved from (else the log next to it, when it is the run's)."""
    path = Path(path)
    if path.suffix == ".mcap":
        regular_file(path)
        new = False
        for info in log_run_infos(path):     # a run of several IMUs: one record per unit
            new = records.add_run(info) or new
        return new
    data, sha = read_json(path)
    fmt = data.get("format")
    if fmt == RESULT_FORMAT:
        content.coefficients(data.get("coefficients"))
        run = result_run_info(data, path)
        return records.add_result(data, sha, str(path.absolute()), run,
                                  derivation_of(data, log_sha256 or run.log_sha256))
    if fmt == TABLE_CHECK_FORMAT:
        as_result = table_check_as_result(data)
        content.coefficients(as_result["coefficients"], "combinations")
        return records.add_result(as_result, sha, str(path.absolute()),
                                  result_run_info(data, path, kind="table-check"))
    if fmt == NOISE_FORMAT:
        return _import_noise(records, data, sha, path)
    if fmt == THERMAL_FORMAT:
        raise NotRecorded("a thermal model: the records hold the calibrations it was fitted to (a thermal run's "
                          "<run-id>.T<k>.result.json), not the model")
    shown = content.text(fmt, "format", 10_000)[:60] if isinstance(fmt, str) else None
    raise IngestError(f"not a {RESULT_FORMAT}, {TABLE_CHECK_FORMAT} or {NOISE_FORMAT} file"
                      + (f" (format {shown!r})" if shown else ""))


def _import_noise(records: Records, data: dict[str, Any], sha: str, path: Path) -> bool:
    """A noise result of a run (a static-noise run's `<run-id>.noise.json`, or `bench noise LOG`): its terms as
    the run's coefficients, `<channel>.<term>` (e.g. gyro_x.arw). The run's unit comes from its log next to the
    file or from the records."""
    source: dict[str, Any] = _dict(data.get("source")) or {}
    if source.get("kind") != "log":
        raise NotRecorded("the noise of a simulated IMU alone (`bench noise --sim`), not of a run of the bench: "
                          "no run to record it with")
    run_id = content.text(source.get("run_id"), "source.run_id", 200)
    if not run_id:
        raise IngestError("the noise result names no run (source.run_id)")
    from_log = _log_next_to(path, source.get("log"), run_id)
    info = None if from_log is None else RunInfo(**{**from_log.__dict__, "kind": "noise"})
    if info is None:
        if not records.run_known(run_id):
            raise IngestError(f"its run {run_id[:60]!r} is not recorded and its log is not next to it: import the "
                              "run's log first")
        info = RunInfo(run_id=run_id, model="", serial="", kind="noise")
    coefficients: dict[str, dict[str, Any]] = {}
    channels: dict[str, Any] = _dict(data.get("channels")) or {}
    for channel, entry in channels.items():
        terms = entry.get("terms") if isinstance(entry, dict) else None
        for term, fit in (terms.items() if isinstance(terms, dict) else ()):
            if isinstance(fit, dict):
                coefficients[f"{channel}.{term}"] = {k: v for k, v in fit.items() if k != "points"}
    content.coefficients(coefficients, "channels")
    return records.add_result({"coefficients": coefficients, "quality": _dict(data.get("summary"))}, sha,
                              str(path.absolute()), info)


def _dict(value: Any) -> dict | None:
    return value if isinstance(value, dict) else None


def result_run_info(data: dict[str, Any], path: Path, kind: str = "calibration") -> RunInfo:
    """The run a result file belongs to, completed from its log when the log lies next to it."""
    run: dict[str, Any] = data["run"] if isinstance(data.get("run"), dict) else {}
    run_id = content.text(run.get("run_id"), "run.run_id", 200)
    if not run_id:
        if str(run.get("mode", "")).startswith("simulator (in memory"):
            raise NotRecorded("an in-memory simulation (`bench thermal sim`), not a run of the bench: no run to "
                              "record it with")
        raise IngestError("the result names no run (run.run_id)")
    imu: dict[str, Any] = run["imu"] if isinstance(run.get("imu"), dict) else {}
    site = run.get("site") if isinstance(run.get("site"), dict) else None
    software = content.text(run.get("software_version") or data.get("software_version"), "run.software_version", 64)
    content.date(run.get("solved_utc"), "run.solved_utc")
    serial = content.text(imu.get("serial"), "run.imu.serial", 200)
    record_id, bench_run = unit_record_id(run_id, serial, run.get("units"))
    info = RunInfo(run_id=record_id, model=content.text(imu.get("model"), "run.imu.model", 200),
                   serial=serial, kind=kind, bench_run=bench_run,
                   mode=content.text(run.get("mode"), "run.mode", 32),
                   operator=content.text(run.get("operator"), "run.operator", 200), site=site,
                   plan=_plan(run.get("positions"), run.get("rotations")), software_version=software,
                   finished_utc=content.date(run.get("finished_utc"), "run.finished_utc"),
                   outcome=content.text(run.get("state"), "run.state", 32))
    from_log = _log_next_to(path, run.get("log"), record_id)
    return info if from_log is None else _merged(info, from_log)


def unit_record_id(run_id: str, serial: str, units: Any) -> tuple[str, str | None]:
    """(record run id, the run it is one unit of) of a result of `serial` in run `run_id`: a unit of a run of
    several IMUs (`units`, the run section's serials of its units, names more than one and this one) is recorded
    as `<run-id>.<serial>` of its run; a run of one IMU as `run_id` of none."""
    if (isinstance(units, list) and len(units) > 1 and serial in units
            and all(isinstance(unit, str) for unit in units)):
        return content.text(f"{run_id}.{serial}", "run.run_id and run.imu.serial", 200), run_id
    return run_id, None


def _log_next_to(path: Path, log_name: Any, run_id: str) -> RunInfo | None:
    """The run (the unit's record, of a run of several IMUs) as the log a result file names describes it, when
    that log lies next to the file and is the run's (None otherwise, or when the log is damaged beyond its
    metadata: the result stands on its own)."""
    if not isinstance(log_name, str) or not log_name:
        return None
    log_path = path.parent / Path(log_name).name      # a name from a file never leaves the result's folder
    if not log_path.is_file():
        return None
    try:
        from_log = log_run_infos(log_path)
    except (OSError, BenchError):
        return None
    return next((info for info in from_log if info.run_id == run_id), None)


def derivation_of(data: dict[str, Any], log_sha256: str | None = None) -> Derivation:
    """How a result came to be, from what its file says: the run's own (`bench run` wrote it: no `solved_by`),
    or derived by `bench solve` from the whole intact log ("re-solve"), from a subset ("subset"), or from a log
    with damage or steps left out ("damaged")."""
    run: dict[str, Any] = data["run"] if isinstance(data.get("run"), dict) else {}
    solved_by = run.get("solved_by")
    if "temperature_block" in run and "thermal" not in run:
        return Derivation("block", f"temperature block T{str(run.get('temperature_block'))[:8]} of a thermal run",
                          log_sha256)
    if not solved_by:
        return Derivation("run", "", log_sha256)
    by = f"{str(solved_by)[:40]} {str(run.get('software_version') or '?')[:40]}"
    recorded_with = str(run.get("recorded_with") or "")[:40]
    damage, left_out = run.get("damage"), run.get("left_out")
    if run.get("subset"):
        return Derivation("subset", f"{by}: subset {_plan(run.get('positions'), run.get('rotations'))[:200]}",
                          log_sha256)
    if (isinstance(damage, list) and damage) or (isinstance(left_out, list) and left_out):
        n_damage = len(damage) if isinstance(damage, list) else 0
        n_left = len(left_out) if isinstance(left_out, list) else 0
        return Derivation("damaged", f"{by}: a damaged log ({n_damage} damage line(s), {n_left} step(s) left out)",
                          log_sha256)
    return Derivation("re-solve", f"{by}: the whole log re-solved" +
                      (f" (recorded with {recorded_with})" if recorded_with else ""), log_sha256)


def _plan(positions: Any, rotations: Any) -> str:
    if not isinstance(positions, str) and not isinstance(rotations, str):
        return ""
    return f"{positions or 'none'} + {rotations or 'none'}"[:400]


def _merged(result: RunInfo, log: RunInfo) -> RunInfo:
    """The result's fields, with what only the log knows (start, table, the log file and its hash)."""
    return RunInfo(**{**log.__dict__, **{k: v for k, v in result.__dict__.items() if v not in (None, "", {}, ())}})


def log_run_infos(path: Path) -> list[RunInfo]:
    """The records of a run as its log's metadata records it (`log_run_info`): one, or for a run of several IMUs
    (its `units` record) one per unit, `<run-id>.<serial>` of the run, each with the log."""
    info, meta = _log_run(path)
    units_json = (meta.get("units") or {}).get("units_json")
    if not isinstance(units_json, str):
        return [info]
    try:
        units = json.loads(units_json)
        identities = [(content.text(unit["model"], "the log's units model", 200),
                       content.text(unit["serial"], "the log's units serial", 200)) for unit in units]
    except (KeyError, TypeError, ValueError) as exc:
        raise IngestError(f"the log's units record is malformed ({exc})") from None
    serials = [serial for _, serial in identities]
    return [RunInfo(**{**info.__dict__, "run_id": unit_record_id(info.run_id, serial, serials)[0], "model": model,
                       "serial": serial, "bench_run": info.run_id}) for model, serial in identities]


def log_run_info(path: Path) -> RunInfo:
    """A run as its log's metadata records it (the log's content hashed); InputError if it is no run log."""
    return _log_run(path)[0]


def _log_run(path: Path) -> tuple[RunInfo, dict[str, Any]]:
    """`log_run_info` and the log's metadata."""
    # the log reader reads the metadata and summary, not the data chunks (those are read when asked for)
    from bench.log.reader import read_log

    log = read_log(str(path), messages=False)   # the metadata is all it needs (a 1 GB log: no states, events)
    meta = log.metadata
    run, imu, plan = meta.get("run") or {}, meta.get("imu") or {}, meta.get("plan") or {}
    run_id = content.text(run.get("run_id"), "the log's run.run_id", 200)
    if not run_id:
        raise IngestError("the log records no run id")
    table_url = ""
    toml_text = (meta.get("config") or {}).get("toml")
    if isinstance(toml_text, str):
        try:
            table = tomllib.loads(toml_text).get("table")
            table_url = str(table.get("url", "")) if isinstance(table, dict) else ""
        except tomllib.TOMLDecodeError:
            pass
    site = meta.get("site") or None
    finished = mcap_finished(path)      # before the hash: a log growing meanwhile is at worst called unfinished
    # a start time the log cannot mean (0001-01-01T00:00:00+05:00) is unknown: the run is still recorded
    return RunInfo(run_id=run_id, model=content.text(imu.get("model"), "the log's imu.model", 200),
                   serial=content.text(imu.get("serial"), "the log's imu.serial", 200),
                   kind="table-check" if run.get("kind") == "table-check" else "calibration",
                   mode=content.text(run.get("mode"), "the log's run.mode", 32), log_path=str(path.absolute()),
                   log_sha256=sha256_of(path),
                   operator=content.text(run.get("operator"), "the log's run.operator", 200),
                   site=dict(site) if site else None, table_url=table_url,
                   plan=_plan(plan.get("positions"), plan.get("rotations")),
                   software_version=content.text(run.get("software_version"), "the log's run.software_version", 64),
                   started_utc=utc(run.get("started_utc")), log_complete=finished,
                   equipment=equipment_used(meta.get("lab") or {})), meta


def equipment_used(lab: dict[str, Any]) -> tuple[tuple[str, str], ...]:
    """(tag, serial) of the equipment a log's `lab` metadata names (`equipment_json`: a list of {"tag", "serial",
    ...}; the serial "" when not given); nothing when it names none or is not that shape."""
    try:
        listed = json.loads(lab.get("equipment_json") or "[]")
    except (TypeError, ValueError):
        return ()
    if not isinstance(listed, list):
        return ()
    return tuple((content.text(item.get("tag"), "the log's lab equipment tag", 64),
                  content.text(item.get("serial"), "the log's lab equipment serial", 200))
                 for item in listed if isinstance(item, dict) and isinstance(item.get("tag"), str))


def table_check_as_result(data: dict[str, Any]) -> dict[str, Any]:
    """A table-check result in the shape `Records.add_result` takes: its combinations as coefficients (arcsec)."""
    coefficients = {}
    for combination in data.get("combinations") or []:
        if isinstance(combination, dict) and isinstance(combination.get("key"), str):
            coefficients[combination["key"]] = {"value": combination.get("value_arcsec"),
                                                "sigma": combination.get("sigma_arcsec"), "unit": "arcsec"}
    return {"coefficients": coefficients,
            "quality": {k: data.get(k) for k in ("reduced_chi2", "dof", "residual_rms_arcsec") if k in data}}


__all__ = ["ImportReport", "IngestError", "NotRecorded", "PATTERNS", "derivation_of", "equipment_used", "find_files",
           "import_file", "import_paths", "log_run_info", "log_run_infos", "result_run_info", "sha256_of",
           "table_check_as_result", "unit_record_id"]
