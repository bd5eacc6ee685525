"""The threads the project starts, and the check that a test leaves none of them running.

Project threads are recognised by name. Every thread that bench/ and drivers/ start is named,
and each name falls under one of `PROJECT_THREAD_PREFIXES`:

- `bench-tui-`: the TUI session's workers (`bench-tui-run`, `bench-tui-monitor`,
  `bench-tui-<command>`, bench/tui/session.py) and the replay player (`bench-tui-replay`,
  bench/tui/replay_session.py)
- `SimCanImu`: the simulated CAN IMU's sender (bench/sim/can_imu.py)
- `modbus-sim-`: the Modbus simulator's event loop (`modbus-sim-loop`) and its RTU pty bridge
  (`modbus-sim-pty-bridge`) (bench/sim/modbus_server.py)
- `sim-`: the line simulators' accept/serve threads (`sim-<function>`, bench/sim/serve.py) and the
  rig's CAN peers (`sim-slcan-pty`, bench/sim/slcan_server.py; `sim-socketcand-<n>`,
  bench/sim/socketcand_server.py)
- `modbus-watchdog`: the Modbus turntable driver's watchdog (drivers/turntable/modbus.py)
- `mcap-inflate`, `can-frames`, `can-stream`, `imu-screen`: `ThreadPoolExecutor` workers of the log reader
  (bench/log/mcap/chunks.py, bench/log/mcap/channel.py, bench/log/format.py, bench/log/can_stream.py: `can-stream`
  reads and decompresses the next `/can/raw` chunks while one is decoded) and of the bulk IMU decoder
  (drivers/imu/bulk.py); an executor names its threads `<prefix>_<n>`
- `allan-channel`, `allan-part`: `ThreadPoolExecutor` workers of the Allan deviation (bench/noise/allan.py):
  the phase accumulated one channel each, the sums over one part of a channel's record each;
  `allan-phase`: the worker that turns a log's decoded samples into the phase while the frames are read
  (bench/noise/from_log.py)

Threads of pytest, Textual (thread workers run in asyncio's default executor, `asyncio_<n>`),
asyncio and third-party libraries are not project threads and are not checked.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Collection

PROJECT_THREAD_PREFIXES: tuple[str, ...] = (
    "bench-tui-",
    "SimCanImu",
    "modbus-sim-",
    "sim-",
    "modbus-watchdog",
    "mcap-inflate",
    "can-frames",
    "can-stream",
    "imu-screen",
    "allan-channel",
    "allan-part",
    "allan-phase",
)

#: How long a test's project threads get to finish after it (its fixtures torn down) before it fails.
GRACE_S = 5.0


def is_project_thread(thread: threading.Thread) -> bool:
    return thread.name.startswith(PROJECT_THREAD_PREFIXES)


def project_threads() -> set[threading.Thread]:
    """The project threads alive now."""
    return {t for t in threading.enumerate() if is_project_thread(t) and t.is_alive()}


def leftover_threads(before: Collection[threading.Thread], grace_s: float = GRACE_S,
                     poll_s: float = 0.05) -> list[threading.Thread]:
    """The project threads alive now that were not alive in `before`, once they have had up to
    `grace_s` to end (returns as soon as there are none)."""
    deadline = time.monotonic() + grace_s
    while True:
        left = sorted(project_threads() - set(before), key=lambda t: t.name)
        if not left or time.monotonic() >= deadline:
            return left
        time.sleep(poll_s)


def check_no_leftover_threads(before: Collection[threading.Thread], grace_s: float = GRACE_S,
                              poll_s: float = 0.05) -> None:
    """Raises AssertionError naming the project threads started since `before` and still alive
    after `grace_s`."""
    left = leftover_threads(before, grace_s, poll_s)
    if left:
        raise AssertionError(f"project threads left running {grace_s:g} s after the test: "
                             f"{', '.join(repr(t.name) for t in left)}")
