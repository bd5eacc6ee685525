"""A real Modbus client, mbpoll (libmodbus), against `bench sim chamber --dialect modbus` on loopback: it reads the
process value and writes the set point at the Watlow F4P's register numbers (docs/hardware/chamber.md).

mbpoll counts holding registers from 1 (reference = the manual's relative number + 1, the F4P manual's absolute
number minus 40000): input 1 value, relative 100 (manual chapter 9), is `-t 4 -r 101`; set point 1, relative 300,
is `-r 301`; decimal of input 1, relative 606, is `-r 607`; auto/manual mode, relative 200, is `-r 201`.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import pytest

from tests.helpers.run import stop_process
from tests.helpers.sim_process import read_until, start_sim

MBPOLL = shutil.which("mbpoll")
pytestmark = pytest.mark.skipif(
    MBPOLL is None, reason="mbpoll (libmodbus's Modbus client, Debian package mbpoll) is not installed; .ci/run "
                           "installs it")


def mbpoll(port: int, reference: int, *values: int, count: int = 1) -> dict[int, int]:
    """One mbpoll request (read `count` holding registers from `reference`, or write `values` there);
    reference -> value of what it printed."""
    assert MBPOLL is not None
    args = [MBPOLL, "-m", "tcp", "-a", "1", "-t", "4", "-r", str(reference), "-p", str(port), "-o", "5"]
    args += ["-c", str(count), "-1", "127.0.0.1"] if not values else ["127.0.0.1", *map(str, values)]
    done = subprocess.run(args, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, (args, done.stdout, done.stderr)
    if values:
        assert f"Written {len(values)} references" in done.stdout, done.stdout
    return {int(ref): int(value) for ref, value in re.findall(r"^\[(\d+)\]:\s+(-?\d+)$", done.stdout, re.M)}


def _console(proc: subprocess.Popen, line: str, marker: str) -> str:
    assert proc.stdin is not None
    proc.stdin.write(line + "\n")
    proc.stdin.flush()
    return read_until(proc, marker)[-1]


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_mbpoll_reads_the_process_value_and_writes_the_set_point_at_the_f4p_numbers():
    proc = start_sim("chamber", "--dialect", "modbus", "--listen", "modbus+tcp://127.0.0.1:0")
    try:
        line = read_until(proc, "listening on")[-1]
        port = int(line.rsplit(":", 1)[1])
        read_until(proc, "Ctrl-C stops")
        assert mbpoll(port, 607) == {607: 1}                  # Decimal, input 1: one place
        assert mbpoll(port, 101) == {101: 230}                # Input 1 Value: 23.0 degC at one decimal
        mbpoll(port, 301, 250)                                # Set Point 1 := 25.0 degC
        assert mbpoll(port, 301) == {301: 250}
        mbpoll(port, 201, 1)                                  # Auto/Manual Mode := auto (run)
        assert "setpoint 25.0 degC, step, running" in _console(proc, "state", "setpoint")
        _console(proc, "alarm over_temperature", "ok")
        # Alarm 1 status 1 (high); 103-105 are other registers to the F4P (unused by the simulator)
        assert mbpoll(port, 101, count=7)[103] == 1
        assert mbpoll(port, 201) == {201: 2}                  # the alarm stopped the run: manual
    finally:
        stop_process(proc)
