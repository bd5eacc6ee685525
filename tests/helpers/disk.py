"""A disk that fills up when told, for the tests of what a full log disk does (the recorder opens its file
through it: `monkeypatch.setattr(bench.log.recorder, "open", FillingDisk.open, raising=False)`)."""

from __future__ import annotations

import errno
import io
import os


class FillingDisk(io.RawIOBase):
    """A file on a disk that fills up when told: once `FillingDisk.full` is set, every write fails with ENOSPC."""

    full = False

    def __init__(self, path: str):
        super().__init__()
        self._file = io.FileIO(path, "wb")

    @classmethod
    def open(cls, path, mode: str = "r", *args, **kwargs):
        assert mode == "wb", mode
        return io.BufferedWriter(cls(path))

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def write(self, data) -> int:
        if FillingDisk.full:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return self._file.write(data)

    def seek(self, pos: int, whence: int = 0) -> int:
        return self._file.seek(pos, whence)

    def tell(self) -> int:
        return self._file.tell()

    def close(self) -> None:
        self._file.close()
        super().close()
