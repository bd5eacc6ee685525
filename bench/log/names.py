"""Names read from a log -> safe file names, in one place.

A log from outside is hostile: its run id, its attachment names and the earlier logs it
names (`run.logs_before`) are text anyone could have written. Such a name never becomes a
path before it passes here (docs/explanation/log-format.md#logs-from-outside: names read from a log never become paths
outside the output folder):

- `safe_name(text)`: the text itself when it is a safe file name (ASCII letters, digits and
  `-_.`, no leading dot, at most `MAX_NAME` characters; so no `/`, no `..`, no NUL), else None.
  The bench's own run ids (`%Y%m%dT%H%M%SZ-<6 hex>`, `bench.run.runner.BenchRun`) are safe names.
- `run_id_of(log)`: the log's run id when it is a safe name, else a safe name made from the
  log's file name, with a note saying so.
- `sibling_log(log_path, entry)`: an earlier log named in `logs_before`: only ever the `.mcap`
  of that base name next to the log; anything else is refused with a one-line reason.
- `output_path(out_dir, name)`: `out_dir / name` for a safe name, `+` allowed (`InputError` otherwise):
  every output file written from a log's names goes through it.
- `shown(value)`: a hostile value quoted on one bounded line, for messages.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

from bench.errors import InputError

#: The longest name taken from a log (run id, attachment name, earlier log).
MAX_NAME = 100
#: The longest output file name (a run id plus suffixes such as `.optimal-24+optimal-5s6r.report.html`).
MAX_FILE_NAME = 255
_SAFE = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]*", re.ASCII)
#: Output file names may also join names with `+` (`<run-id>.optimal-24+optimal-5s6r.result.json`).
_SAFE_OUTPUT = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._+-]*", re.ASCII)
_UNSAFE_RUN = re.compile(r"[^A-Za-z0-9._-]+", re.ASCII)
#: The run id `BenchRun` makes: UTC start time and 3 random bytes.
BENCH_RUN_ID = re.compile(r"\d{8}T\d{6}Z-[0-9a-f]{6}", re.ASCII)
LOG_SUFFIX = ".mcap"


def safe_name(text: object, max_length: int = MAX_NAME) -> str | None:
    """`text` if it is a safe file name (see the module docstring), else None."""
    if not isinstance(text, str) or not 0 < len(text) <= max_length or not _SAFE.fullmatch(text):
        return None
    return text


def shown(value: object, limit: int = 60) -> str:
    """`value` quoted for a one-line message: control characters escaped, at most `limit` characters."""
    text = json.dumps(value if isinstance(value, str) else str(value), ensure_ascii=True)
    return text if len(text) <= limit else text[:limit - 4] + '..."'


def fallback_name(log_path: str | Path) -> str:
    """A safe name made from a log's file name (its base name without `.mcap`; `log` if nothing is left)."""
    stem = Path(str(log_path)).name.removesuffix(LOG_SUFFIX)
    name = _UNSAFE_RUN.sub("-", stem).lstrip(".-")[:MAX_NAME].rstrip(".")
    return safe_name(name) or "log"


def run_id_of(log_path: str | Path, metadata: dict) -> tuple[str, str | None]:
    """(the run id to name outputs by, a note when the log's own was refused) of a log's metadata."""
    raw = (metadata.get("run") or {}).get("run_id")
    if raw in (None, ""):
        return fallback_name(log_path), None
    if safe_name(raw) is not None:
        return str(raw), None
    name = fallback_name(log_path)
    return name, (f"the log's run id {shown(raw)} is not a safe file name: outputs are named after the log file "
                  f"({name})")


def logs_before(metadata: dict) -> tuple[list[str], str | None]:
    """The entries of a log's `run.logs_before` (a JSON list of strings), and a note when it is malformed."""
    raw = (metadata.get("run") or {}).get("logs_before")
    if raw in (None, ""):
        return [], None
    try:
        entries = json.loads(raw)
    except (TypeError, ValueError):
        return [], f"its logs_before record {shown(raw)} is not a JSON list: ignored"
    if not isinstance(entries, list):
        return [], f"its logs_before record {shown(raw)} is not a JSON list: ignored"
    return entries, None


def sibling_log(log_path: str | Path, entry: object) -> tuple[Path | None, str]:
    """An earlier log a log names: (the `.mcap` of that base name next to the log, "") or (None, why not).

    The entry's folder is never used (it was where the file was when the log was written,
    or anything at all in a crafted log): only its base name, looked up next to the log.
    """
    if not isinstance(entry, str):
        return None, f"names {shown(entry)} as an earlier log, which is not a file name: skipped"
    base = re.split(r"[/\\]", entry)[-1]
    name = safe_name(base)
    if name is None or not name.endswith(LOG_SUFFIX) or name == LOG_SUFFIX:
        return None, f"names {shown(entry)} as an earlier log, which is not a .mcap file next to it: skipped"
    here = Path(str(log_path))
    path = here.parent / name
    if path.name == here.name:
        return None, f"names itself ({shown(entry)}) as an earlier log: skipped"
    return path, ""


def output_path(out_dir: str | Path, name: str) -> Path:
    """`out_dir / name`; `InputError` unless `name` is a safe file name, `+` allowed (never a path out of `out_dir`)."""
    if not 0 < len(name) <= MAX_FILE_NAME or not _SAFE_OUTPUT.fullmatch(name):
        raise InputError(f"refusing to write {shown(name)}: not a safe file name")
    return Path(out_dir) / name


__all__ = ["BENCH_RUN_ID", "LOG_SUFFIX", "MAX_FILE_NAME", "MAX_NAME", "fallback_name", "logs_before", "output_path",
           "run_id_of", "safe_name", "shown", "sibling_log"]
