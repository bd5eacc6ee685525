"""A throwaway PostgreSQL server in a temporary folder, on loopback, when the PostgreSQL binaries are installed.

`postgres_server()` finds `initdb` and `pg_ctl` (on PATH, else Debian's /usr/lib/postgresql/N/bin),
initialises a cluster in a new temporary folder (as the `postgres` user when running as root:
initdb refuses root), starts it on 127.0.0.1 on a free port without fsync, and stops it
(immediate) and removes the folder afterwards. No binaries: `pytest.skip` says so, naming the package.
"""

from __future__ import annotations

import contextlib
import glob
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path
from typing import Iterator

import pytest

SKIP_REASON = ("PostgreSQL binaries (initdb, pg_ctl) not installed: the PostgreSQL tests are SKIPPED "
               "(apt-get install postgresql; .ci/run installs it)")


def _binary(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    candidates = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    return candidates[-1] if candidates else None


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def postgres_server() -> Iterator[str]:
    """Yields the server's base URL `postgresql+psycopg://bench@127.0.0.1:PORT`; skips without the binaries."""
    initdb, pg_ctl = _binary("initdb"), _binary("pg_ctl")
    if initdb is None or pg_ctl is None:
        pytest.skip(SKIP_REASON)
    pytest.importorskip("psycopg", reason="psycopg (the test extra installs it) is missing: PostgreSQL tests SKIPPED")
    as_user: list[str] = []
    folder = Path(tempfile.mkdtemp(prefix="bench-pg-"))
    if os.geteuid() == 0:
        runuser = shutil.which("runuser")
        try:
            import pwd

            pg = pwd.getpwnam("postgres")
        except KeyError:
            pg = None
        if runuser is None or pg is None:
            shutil.rmtree(folder, ignore_errors=True)
            pytest.skip("running as root without a postgres user (initdb refuses root): PostgreSQL tests SKIPPED")
        os.chown(folder, pg.pw_uid, pg.pw_gid)
        as_user = [runuser, "-u", "postgres", "--"]
    data = folder / "data"
    port = _free_port()
    started = False
    try:
        subprocess.run([*as_user, initdb, "-D", str(data), "-A", "trust", "-U", "bench", "--no-sync", "-E", "UTF8"],
                       check=True, capture_output=True, timeout=120)
        subprocess.run([*as_user, pg_ctl, "-D", str(data), "-w", "-t", "60", "-l", str(folder / "server.log"),
                        "-o", f"-c listen_addresses=127.0.0.1 -p {port} -k {folder} -c fsync=off", "start"],
                       check=True, capture_output=True, timeout=90)
        started = True
        yield f"postgresql+psycopg://bench@127.0.0.1:{port}"
    finally:
        if started:
            subprocess.run([*as_user, pg_ctl, "-D", str(data), "-m", "immediate", "-w", "-t", "30", "stop"],
                           capture_output=True, timeout=60)
        shutil.rmtree(folder, ignore_errors=True)


def create_database(base_url: str, name: str) -> str:
    """A new empty database on the server; returns its URL."""
    import psycopg
    from psycopg import sql

    with psycopg.connect(base_url.replace("postgresql+psycopg", "postgresql") + "/postgres", autocommit=True) as conn:
        conn.execute(sql.SQL("CREATE DATABASE {}").format(sql.Identifier(name)))
    return f"{base_url}/{name}"
