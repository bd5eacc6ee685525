"""A configuration `bench sim rig --write-config` wrote is valid only while that rig runs (issue 33, item 14).

The rig's pty (`/dev/pts/N`) and ports go to other processes once it stops. The written file says so in a
comment and names the rig in `[imu.rig]` (its id, process id and process start); `bench run` refuses the file
before opening anything once that rig has stopped, and refuses an SLCAN adapter that answers another serial
number than the rig's id, naming the rig it expected. Ptys and loopback only; every wait is bounded.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys

import pytest

from bench.config.load import load_config, parse_config
from bench.config.rig import RigIdentity, this_rig
from bench.run.imu_check import ImuCheckError, check_rig_adapter, check_rig_running
from bench.sim.rig import SimRig, rig_config_text
from drivers.imu.receiver import open_bus
from tests.helpers.run import REPO, config_text, stop_process
from tests.helpers.sim_process import read_until, start_sim


def _ended_pid() -> int:
    """The pid of a process that has ended (and been reaped)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait(timeout=30)
    return child.pid


def test_the_written_file_says_it_is_valid_only_while_the_rig_runs_and_names_it():
    config = parse_config(config_text(rate_hz=100.0))
    with SimRig(config) as rig:
        peer = rig.serve_slcan()
        text = rig_config_text(config, "tcp://127.0.0.1:5025", "scpi", peer, rig=rig.identity)
    me = rig.identity
    assert me.pid == os.getpid() and len(me.id) == 4 and me.started_utc.endswith("Z")
    head = text[:text.index("format =")]
    assert f"Valid only while the rig that wrote it runs: rig {me.id} (`bench sim rig`, pid {me.pid}, " \
           f"started {me.started_utc})" in head
    assert f"the system gives {peer.where}, tcp://127.0.0.1:5025 to other processes" in head
    assert parse_config(text).imu.rig == me
    # without a rig (the truth the rig's options build) nothing of it is written
    assert "[imu.rig]" not in rig_config_text(config, "sim", "scpi", peer) and config.imu.rig is None


def test_a_rig_that_stopped_is_refused_naming_it():
    gone = RigIdentity("1C2B", _ended_pid(), "2026-11-27T20:40:00.00Z")
    with pytest.raises(ImuCheckError, match=r"written for rig 1C2B \(`bench sim rig`, pid \d+, started "
                                            r"2026-11-27T20:40:00.00Z\), which is not running: /dev/pts/7 may "
                                            "belong to another process now"):
        check_rig_running(gone, "/dev/pts/7")
    # its pid given to another process since (this one, started at another time) is not the rig either
    reused = RigIdentity("1C2B", os.getpid(), "2000-01-01T00:00:00.00Z")
    with pytest.raises(ImuCheckError, match="which is not running"):
        check_rig_running(reused, "/dev/pts/7")
    check_rig_running(this_rig(), "/dev/pts/7")      # the rig in this process runs
    check_rig_running(None, "/dev/pts/7")            # a file no rig wrote


@pytest.mark.parametrize("client", ["bench", "python-can"])
def test_an_slcan_adapter_that_is_not_the_rigs_is_refused_naming_the_rig_expected(client):
    config = parse_config(config_text(rate_hz=100.0))
    with SimRig(config) as other:
        peer = other.serve_slcan()
        expected = dataclasses.replace(this_rig(), id="0000" if other.identity.id != "0000" else "0001")
        bus = open_bus({"interface": "slcan", "channel": peer.channel, "bitrate": 1_000_000, "slcan_client": client})
        try:
            with pytest.raises(ImuCheckError) as caught:
                check_rig_adapter(bus, expected, peer.where)
            check_rig_adapter(bus, other.identity, peer.where)     # the rig's own adapter passes
        finally:
            bus.shutdown()
    assert str(caught.value).startswith(f"the SLCAN adapter on {peer.where} answers serial number "
                                        f"{other.identity.id!r}, not rig {expected.id} (`bench sim rig`, pid ")


@pytest.mark.slow
def test_bench_run_refuses_the_file_of_a_rig_that_stopped_before_opening_anything(tmp_path):
    written = tmp_path / "bench.toml"
    rig = start_sim("rig", "--imu-rate-hz", "100", "--write-config", str(written))
    try:
        read_until(rig, "Ctrl-C stops")
        identity = load_config(written).imu.rig
        assert identity is not None and identity.pid == rig.pid and identity.running()
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
    finally:
        stop_process(rig)
    assert not identity.running()
    run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out",
                          str(tmp_path / "runs"), "--quiet", "--no-db"], cwd=REPO, capture_output=True, text=True,
                         timeout=120)
    lines = run.stderr.strip().splitlines()
    assert run.returncode == 2 and len(lines) == 1, run.stderr
    assert f"written for rig {identity.id} (`bench sim rig`, pid {rig.pid}, started {identity.started_utc}), " \
           "which is not running" in lines[0], lines[0]
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())
