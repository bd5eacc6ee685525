"""Files given by the user, both ways: every input is a hostile file, no output lands on an input or a raw log.

Reading (`open_input`, `read_input_bytes`, `read_input_text`): the path is `os.stat`ed before it is
opened and must be a regular file (a FIFO, a device such as /dev/zero, a socket or a folder is refused
in one line, never read); it is opened with O_NONBLOCK (a FIFO swapped in between the stat and the open
cannot block) and checked again on the open descriptor; a size cap is checked on the stat and enforced
on the read (`MAX_INPUT_FILE_BYTES`, 16 MiB, for every JSON file the bench reads: results, thermal
models, noise results, the files a configuration names). Run logs are opened the same way without a cap
(the log reader bounds what it does with them).

Writing (`check_output`, `replaced_output`, `write_output_text`): an output is refused when it is the
same file (device and inode, `os.path.samefile`: a hard link or a symlink counts) as any input of the
command, and when it is an existing run log of the bench (an MCAP file whose metadata names a run)
unless the command was given `--force`. The output is written to a temporary name in the same folder
and renamed into place once complete: a failure leaves the old file as it was, never half of a new one.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import stat
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any, BinaryIO

from bench.errors import InputError

#: the largest JSON file read: a result, a thermal model, a noise result, a reference or check file (a result
#: of the bench is a few tens of kB)
MAX_INPUT_FILE_BYTES = 16 << 20

_KINDS = ((stat.S_ISDIR, "a folder"), (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"))
_MCAP_MAGIC = b"\x89MCAP0\r\n"
_OP_HEADER, _OP_METADATA, _OP_CHUNK = 0x01, 0x0C, 0x06
#: the most digits of an integer in a JSON file (counters and sample counts need 19; Python refuses over 4300)
MAX_JSON_INT_DIGITS = 30
#: how far into a file the run metadata of a log is looked for (the recorder writes it after the header)
_RUN_LOG_HEAD_BYTES = 1 << 20


class InputFileError(InputError):
    """A path that cannot be read as the file it should be (not a regular file, too large); one line."""


class OutputFileError(InputError):
    """An output that would replace an input or a run log; one line."""


def file_kind(mode: int) -> str:
    """'a FIFO', 'a character device', ... for a `st_mode` that is not a regular file."""
    return next((name for test, name in _KINDS if test(mode)), "a special file")


def _short(path: str | os.PathLike) -> str:
    text = os.fspath(path)
    return text if len(text) <= 200 else f"{text[:200]}... ({len(text)} characters)"


def open_input(path: str | os.PathLike, *, max_bytes: int | None = MAX_INPUT_FILE_BYTES,
               what: str = "file") -> BinaryIO:
    """The regular file `path` open for binary reading, at most `max_bytes` long (None: any size).

    `InputFileError` (one line) for anything else; `OSError` when it cannot be opened at all.
    """
    info = os.stat(path)
    if not stat.S_ISREG(info.st_mode):
        raise InputFileError(f"{_short(path)}: not a regular file ({file_kind(info.st_mode)}): not a {what}")
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    try:
        info = os.fstat(fd)   # what was opened, should the name have changed since the stat
        if not stat.S_ISREG(info.st_mode):
            raise InputFileError(f"{_short(path)}: not a regular file ({file_kind(info.st_mode)}): not a {what}")
        if max_bytes is not None and info.st_size > max_bytes:
            raise InputFileError(f"{_short(path)}: {info.st_size} bytes, more than a {what} holds "
                                 f"(at most {max_bytes})")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_input_bytes(path: str | os.PathLike, *, max_bytes: int = MAX_INPUT_FILE_BYTES, what: str = "file") -> bytes:
    """The bytes of the regular file `path`, at most `max_bytes` (also when it grows while read)."""
    with open_input(path, max_bytes=max_bytes, what=what) as f:
        data = f.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputFileError(f"{_short(path)}: more than a {what} holds (at most {max_bytes} bytes)")
    return data


def read_input_text(path: str | os.PathLike, *, max_bytes: int = MAX_INPUT_FILE_BYTES, what: str = "file") -> str:
    """`read_input_bytes` decoded as UTF-8 (`InputFileError` naming the byte otherwise)."""
    data = read_input_bytes(path, max_bytes=max_bytes, what=what)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise InputFileError(f"{_short(path)}: not UTF-8 (byte {exc.start}): not a {what}") from None


class _Refused(ValueError):
    """A number `parse_json` does not take."""


def _json_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_JSON_INT_DIGITS:
        raise _Refused(f"an integer of {len(text.lstrip('-'))} digits (at most {MAX_JSON_INT_DIGITS})")
    return int(text)


def _json_float(text: str) -> float:
    value = float(text)
    if not math.isfinite(value):
        raise _Refused(f"the number {text[:40]} is beyond the range of a float")
    return value


def _json_constant(name: str) -> Any:
    raise _Refused(f"{name} is not a number")


def parse_json(text: str | bytes, origin: str) -> Any:
    """JSON from a file from outside, the one boundary for its numbers: an integer of more than
    `MAX_JSON_INT_DIGITS` digits, a number beyond a float (1e400), NaN or Infinity, or nesting deeper than
    Python's recursion limit is an `InputFileError` (one line naming `origin`), as is invalid JSON."""
    try:
        return json.loads(text, parse_int=_json_int, parse_float=_json_float, parse_constant=_json_constant)
    except json.JSONDecodeError as exc:
        raise InputFileError(f"{_short(origin)}:{exc.lineno}: invalid JSON: {exc.msg}") from None
    except _Refused as exc:
        raise InputFileError(f"{_short(origin)}: {exc}") from None
    except RecursionError:
        raise InputFileError(f"{_short(origin)}: JSON nested too deeply") from None
    except (ValueError, UnicodeDecodeError) as exc:
        raise InputFileError(f"{_short(origin)}: invalid JSON: {str(exc)[:100]}") from None


def _string(buf: bytes, pos: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", buf, pos)
    if pos + 4 + n > len(buf):
        raise ValueError("string past the end")
    return buf[pos + 4:pos + 4 + n].decode("utf-8", "replace"), pos + 4 + n


def is_run_log(path: str | os.PathLike) -> bool:
    """Whether `path` is a regular file holding a run log of the bench: MCAP whose metadata names a run
    (`run`), written before its first chunk. Reads at most 1 MiB; False for anything it cannot read."""
    try:
        with open_input(path, max_bytes=None, what="run log") as f:
            head = f.read(_RUN_LOG_HEAD_BYTES)
    except (OSError, InputError):
        return False
    if not head.startswith(_MCAP_MAGIC):
        return False
    pos = len(_MCAP_MAGIC)
    try:
        while pos + 9 <= len(head):
            op, length = struct.unpack_from("<BQ", head, pos)
            body = pos + 9
            if op == _OP_METADATA and _string(head, body)[0] == "run":
                return True
            if op == _OP_HEADER and not _string(head, _string(head, body)[1])[0].startswith("turntable-bench/"):
                return False
            if op == _OP_CHUNK:
                return False
            pos = body + length
    except (struct.error, ValueError):
        return False
    return False


def _same(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    try:
        return os.path.samefile(a, b)
    except (OSError, ValueError):
        return False


def check_output(out: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), *, force: bool = False,
                 option: str = "--out") -> None:
    """Refuse (`OutputFileError`) an output that is one of `inputs` (same device and inode) or an existing
    run log of the bench (unless `force`)."""
    if not os.path.lexists(out):
        return
    for source in inputs:
        if _same(out, source):
            raise OutputFileError(f"{option} {_short(out)} is {_short(source)}, a file this command reads "
                                  f"(the same file on disk): write to another file")
    if is_run_log(out) and not force:
        raise OutputFileError(f"{option} {_short(out)} is a run log: a raw log is never written over "
                              f"(write to another file, or say --force to replace it)")


@contextlib.contextmanager
def replaced_output(out: str | os.PathLike, inputs: Iterable[str | os.PathLike] = (), *, force: bool = False,
                    option: str = "--out") -> Iterator[Path]:
    """Check `out` (`check_output`) and yield a temporary path beside it, renamed to `out` when the block ends
    without an error (removed otherwise). An existing special file (/dev/null) is written in place."""
    out = Path(out)
    check_output(out, inputs, force=force, option=option)
    try:
        special = not stat.S_ISREG(os.stat(out).st_mode)
    except OSError:
        special = False
    if special:
        yield out
        return
    temporary = out.with_name(f".{out.stem[:100]}.{os.getpid()}.partial{out.suffix[:20]}")
    try:
        yield temporary
        os.replace(temporary, out)
    finally:
        with contextlib.suppress(OSError):
            temporary.unlink()


def write_output_text(out: str | os.PathLike, text: str, inputs: Iterable[str | os.PathLike] = (), *,
                      force: bool = False, option: str = "--out") -> None:
    """Write `text` (UTF-8) to `out` through `replaced_output`."""
    with replaced_output(out, inputs, force=force, option=option) as temporary:
        temporary.write_text(text, encoding="utf-8")


def folder_reason(exc: OSError, folder: str | os.PathLike | None = None) -> str:
    """Why `folder` cannot be made, in words: a file where it or one of its parents should be is named (not "File
    exists" or "Not a directory")."""
    if isinstance(exc, (FileExistsError, NotADirectoryError)):
        path = Path(folder) if folder is not None else None
        if path is None or path.is_file():
            return "it is a file, not a folder"
        in_the_way = next((parent for parent in path.parents if parent.is_file()), None)
        if in_the_way is not None:
            return f"{_short(in_the_way)} is a file, not a folder"
    return str(exc.strerror or exc)


def make_output_folder(folder: str | os.PathLike, option: str = "--out") -> Path:
    """`folder`, made if missing (`OutputFileError` in one line when it cannot be)."""
    path = Path(folder)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputFileError(f"{option} {_short(path)}: {folder_reason(exc, path)}") from exc
    return path


__all__ = ["MAX_INPUT_FILE_BYTES", "MAX_JSON_INT_DIGITS", "InputFileError", "OutputFileError", "check_output",
           "file_kind", "folder_reason", "is_run_log", "make_output_folder", "open_input", "parse_json",
           "read_input_bytes", "read_input_text", "replaced_output", "write_output_text"]
