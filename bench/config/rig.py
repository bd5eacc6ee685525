"""Which `bench sim rig` a configuration was written for (`[imu.rig]`), and whether that rig still runs.

A rig serves its table and IMU on a pty or a port that the system hands to another process once the rig stops:
a configuration it wrote is valid only while it runs. The file names the rig (its process id, when that process
started, and an id its simulated SLCAN adapter answers as its serial number), so that `bench run` refuses the
file once the rig has gone (before opening anything, a pty that is someone's terminal now included), and an
adapter that is not the rig's, naming the rig it expected.
"""

from __future__ import annotations

import datetime
import os
import zlib
from dataclasses import dataclass

#: seconds the start times of one process may differ by when computed twice (the boot time is whole seconds)
START_TOLERANCE_S = 2.0


@dataclass(frozen=True)
class RigIdentity:
    """`[imu.rig]`: the rig's id (its SLCAN adapter's serial number), process id and process start (ISO 8601 UTC)."""

    id: str
    pid: int | None = None
    started_utc: str = ""

    def describe(self) -> str:
        """'rig 1C2B (`bench sim rig`, pid 1234, started 2026-11-27T20:40:00.12Z)'."""
        about = ", ".join(["`bench sim rig`", *([f"pid {self.pid}"] if self.pid is not None else []),
                           *([f"started {self.started_utc}"] if self.started_utc else [])])
        return f"rig {self.id} ({about})"

    def running(self) -> bool:
        """True when the rig's process still runs (its pid, started when the file says, where the system tells
        start times; its pid alone elsewhere). A file without a pid cannot tell: True."""
        if self.pid is None:
            return True
        if not _alive(self.pid):
            return False
        started, recorded = process_started(self.pid), _parse(self.started_utc)
        return started is None or recorded is None or abs((started - recorded).total_seconds()) <= START_TOLERANCE_S


def this_rig() -> RigIdentity:
    """The identity of the rig in this process."""
    pid = os.getpid()
    started = process_started(pid) or datetime.datetime.now(datetime.timezone.utc)
    text = started.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-4] + "Z"
    return RigIdentity(f"{zlib.crc32(f'{pid} {text}'.encode()) & 0xFFFF:04X}", pid, text)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:         # another user's process: it exists
        return True
    except OSError:
        return False
    return True


def process_started(pid: int) -> datetime.datetime | None:
    """When process `pid` started (UTC), from /proc (Linux); None where the system does not say."""
    try:
        with open(f"/proc/{pid}/stat", encoding="ascii", errors="replace") as f:
            stat = f.read()
        with open("/proc/stat", encoding="ascii", errors="replace") as f:
            boot_s = next(int(line.split()[1]) for line in f if line.startswith("btime "))
        # the fields after the command name (which may hold spaces and parentheses): starttime is field 22
        ticks = int(stat[stat.rindex(")") + 2:].split()[19])
        return datetime.datetime.fromtimestamp(boot_s + ticks / os.sysconf("SC_CLK_TCK"), datetime.timezone.utc)
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def _parse(text: str) -> datetime.datetime | None:
    try:
        parsed = datetime.datetime.fromisoformat(text.replace("Z", "+00:00"))
    except ValueError:
        return None
    return parsed if parsed.tzinfo is not None else None


__all__ = ["RigIdentity", "process_started", "this_rig"]
