"""`bench sim rig`'s CAN peers: the SLCAN adapter on a pty and socketcand on TCP.

Codecs are checked with the byte strings the protocol documents print (Lawicel SLCAN;
socketcand's doc/protocol.md); the servers with python-can's own client classes
(`can.Bus(interface="slcan")`, `can.Bus(interface="socketcand")`) receiving the simulated
IMU's frames in wall-clock time, decoded by the bench's `ImuReceiver` with no loss, across
a disconnect and a reconnect. Loopback and ptys only; every wait is bounded.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import signal
import subprocess
import sys
import time
from pathlib import Path

import can
import numpy as np
import pytest

from bench.config.load import load_config, parse_config
from bench.log.reader import read_log
from bench.model.result import coefficient_table
from bench.sim.rig import SimRig, apply_imu_command, imu_status, rig_config_text
from bench.sim.slcan_server import SlcanError, SlcanPeer, encode_frame, split_commands
from bench.sim.socketcand_server import SocketcandError, SocketcandSession, split_elements
from bench.sim.socketcand_server import encode_frame as socketcand_frame
from drivers.imu import DEFAULT_DBC, default_fd_layout
from drivers.imu.receiver import INCOMPLETE_READ_FILTER, SOCKETCAND_LOGGER, ImuReceiver, open_bus
from drivers.turntable import open_turntable
from tests.helpers.run import REPO, cli, config_text, only_file, stop_process, wait_for
from tests.helpers.sim_process import read_until, start_sim

RATE_HZ = 200.0


@pytest.fixture
def rig():
    config = parse_config(config_text(rate_hz=RATE_HZ, noise="true"))
    with SimRig(config) as sim_rig:
        yield sim_rig


# -- SLCAN codec and command peer ----------------------------------------------------

def test_slcan_frames_as_the_protocol_prints_them():
    # Lawicel: "t10021133[CR]" = id 0x100, 2 bytes 0x11 0x33; "T0000010021133[CR]" the same with a 29-bit id
    assert encode_frame(can.Message(arbitration_id=0x100, data=b"\x11\x33", is_extended_id=False)) == b"t10021133\r"
    assert encode_frame(can.Message(arbitration_id=0x100, data=b"\x11\x33", is_extended_id=True)) == (
        b"T0000010021133\r")
    assert encode_frame(can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False)) == b"t7FF0\r"
    # with timestamps on (Z1): 4 hex digits of milliseconds modulo 60000
    assert encode_frame(can.Message(arbitration_id=0x1, data=b"\xab", is_extended_id=False), 60001) == (
        b"t0011AB0001\r")
    with pytest.raises(SlcanError, match="not CAN FD"):
        encode_frame(can.Message(arbitration_id=0x100, data=bytes(12), is_fd=True, is_extended_id=False))


def test_slcan_peer_answers_as_a_canable():
    peer = SlcanPeer()
    # what python-can's slcan client sends on open with a bit rate: C, S8, "" (no data bit rate), O, O
    assert [peer.handle(c) for c in (b"C", b"S8", b"", b"O")] == [b"\r", b"\r", b"\r", b"\r"]
    assert peer.is_open and peer.bitrate == 1_000_000
    assert peer.handle(b"O") == b"\a"               # already open
    assert peer.handle(b"S6") == b"\a"              # no bit rate change while open
    assert peer.handle(b"V") == b"V1013\r" and peer.handle(b"N") == b"NA123\r" and peer.handle(b"F") == b"F00\r"
    assert peer.handle(b"t10021133") == b"z\r" and peer.handle(b"T0000010021133") == b"Z\r"
    assert peer.handle(b"t1002113") == b"\a"        # data shorter than its dlc
    for unsupported in (b"s031C", b"Y2", b"d1009" + b"00" * 12, b"x", b"S9", b"\xff"):
        assert peer.handle(unsupported) == b"\a", unsupported
    assert peer.handle(b"C") == b"\r" and not peer.is_open
    assert peer.handle(b"t10021133") == b"\a"       # closed: nothing to send on
    assert peer.handle(b"L") == b"\r" and peer.listen_only and peer.handle(b"t10021133") == b"\a"


def test_slcan_command_split():
    buffer = bytearray(b"C\rS8\r\r\nO\rV\rpartial")      # LF is not a terminator: ignored
    assert split_commands(buffer) == [b"C", b"S8", b"", b"O", b"V"]
    assert buffer == bytearray(b"partial")
    junk = bytearray(b"x" * 100)
    assert split_commands(junk) == [b"x" * 64] and not junk


# -- socketcand codec and session ----------------------------------------------------

def test_socketcand_frames_as_the_protocol_prints_them():
    # doc/protocol.md: "< frame 123 23.424242 11223344 >"
    msg = can.Message(arbitration_id=0x123, data=bytes.fromhex("11223344"), is_extended_id=False)
    assert socketcand_frame(msg, 23.424242) == b"< frame 123 23.424242 11223344 >"
    ext = can.Message(arbitration_id=0x123, data=b"", is_extended_id=True)
    assert socketcand_frame(ext, 1.9999999) == b"< frame 00000123 2.000000  >"
    with pytest.raises(SocketcandError, match="not CAN FD"):
        socketcand_frame(can.Message(arbitration_id=1, data=bytes(12), is_fd=True), 0.0)


def test_socketcand_session_handshake_and_commands():
    session = SocketcandSession()
    assert session.handle("rawmode") == b"< error open a bus first >"
    assert session.handle("open vcan1").startswith(b"< error")
    assert session.handle("open can0") == b"< ok >"
    assert session.handle("rawmode") == b"< ok >" and session.raw
    assert session.handle("send 123 2 11 22") == b"" and session.sent == ["send 123 2 11 22"]
    assert session.handle("send 123 2 11").startswith(b"< error")
    assert session.handle("echo") == b"< echo >"
    assert session.handle("bcmmode").startswith(b"< error")
    buffer = bytearray(b"junk< open  can0 >< rawmode ><send 1 0>< part")
    assert split_elements(buffer) == ["open can0", "rawmode", "send 1 0"]
    assert buffer == bytearray(b"< part")


# -- python-can's clients against the rig's peers --------------------------------------

def _receive(receiver: ImuReceiver, samples: int, timeout_s: float = 20.0) -> np.ndarray:
    """Poll until `samples` samples came (bounded); their counters."""
    counters = []
    got = 0
    deadline = time.monotonic() + timeout_s
    for _ in range(int(timeout_s / 0.02) + 1):
        block = receiver.poll(timeout_s=0.02)
        counters.append(block.counter)
        got += len(block)
        if got >= samples or time.monotonic() > deadline:
            break
    assert got >= samples, f"{got} samples in {timeout_s} s, wanted {samples}"
    return np.concatenate(counters)


def _assert_no_loss(receiver: ImuReceiver, counters: np.ndarray) -> None:
    stats = receiver.stats
    assert np.all(np.diff(counters) == 1), "a counter gap"
    assert stats.frame_faults == 0 and stats.incomplete_samples == 0 and stats.counter_gaps == 0, stats
    assert stats.late == 0 and stats.duplicates == 0, stats


def _sessions(rig: SimRig, bus_kwargs: dict) -> None:
    layout, rate_hz = rig.config.imu.layout, rig.config.imu.rate_hz
    rig.start()
    for _ in range(2):                          # connect, receive, disconnect; then again
        with ImuReceiver(bus_kwargs, layout, rate_hz) as receiver:
            counters = _receive(receiver, 100)
            _assert_no_loss(receiver, counters)
        assert receiver.bus._is_shutdown
    # a fault typed on the console reaches the next client: one dropped frame is one incomplete sample
    with ImuReceiver(bus_kwargs, layout, rate_hz) as receiver:
        _receive(receiver, 20)
        assert apply_imu_command(rig, ["drop", "1"]) == "ok"
        _receive(receiver, 40)
        assert receiver.stats.incomplete_samples == 1, receiver.stats
    assert "frames out" in imu_status(rig)


def test_python_can_slcan_client_receives_every_sample_and_reconnects(rig):
    peer = rig.serve_slcan()
    # python-can's own slcan class (the bench reads SLCAN with its bulk reader unless told otherwise)
    _sessions(rig, {"interface": "slcan", "channel": peer.channel, "bitrate": peer.bitrate, "sleep_after_open": 0,
                    "slcan_client": "python-can"})
    server = rig.server(0)
    wait_for(lambda: not server.peer.is_open, 5.0, "the last client's 'C' to close the channel")
    assert server.clients == 3
    assert server.frames_dropped == 0


def test_python_can_socketcand_client_receives_every_sample_and_reconnects(rig):
    peer = rig.serve_socketcand()
    assert peer.channel == "can0"
    _sessions(rig, {"interface": "socketcand", "channel": "can0", **peer.bus_options})
    server = rig.server(0)
    assert server.clients == 3 and server.frames_dropped == 0


def test_a_client_that_goes_away_without_closing_leaves_the_slcan_pty_usable(rig):
    peer = rig.serve_slcan()
    rig.start()
    kwargs = {"interface": "slcan", "channel": peer.channel, "sleep_after_open": 0}
    bus = can.Bus(**kwargs)
    assert bus.recv(5.0) is not None
    bus.serialPortOrig.close()                  # gone without 'C', as a killed process
    server = rig.server(0)
    wait_for(lambda: not server.peer.is_open, 5.0, "the hang-up to close the channel")
    with ImuReceiver(kwargs, rig.config.imu.layout, RATE_HZ) as receiver:       # the bench's bulk reader
        assert type(receiver.bus).__name__ == "BulkSlcanBus"
        _assert_no_loss(receiver, _receive(receiver, 50))
    can.BusABC.shutdown(bus)                    # its port is closed already: only the bus's own bookkeeping


def test_fd_layouts_are_refused_for_slcan_and_socketcand():
    config = parse_config(config_text(rate_hz=RATE_HZ))
    config = dataclasses.replace(config, imu=dataclasses.replace(config.imu, layout=default_fd_layout(), fd=True))
    with SimRig(config) as fd_rig:
        with pytest.raises(ValueError, match="classic CAN frames only"):
            fd_rig.serve_slcan()
        with pytest.raises(ValueError, match="classic CAN frames only"):
            fd_rig.serve_socketcand()


def test_the_written_configuration_loads_and_rebuilds_the_truth(rig, tmp_path):
    peer = rig.serve_socketcand()
    text = rig_config_text(rig.config, "tcp://127.0.0.1:5025", "scpi", peer)
    path = tmp_path / "bench.toml"
    path.write_text(text)
    written = load_config(path)
    assert written.imu.bus_kwargs() == {"interface": "socketcand", "channel": "can0", "fd": False,
                                        "host": peer.bus_options["host"], "port": peer.bus_options["port"]}
    assert written.table.url == "tcp://127.0.0.1:5025" and written.imu.rate_hz == RATE_HZ
    assert written.sim.noise == rig.config.sim.noise and written.sim.seed == rig.config.sim.seed
    assert np.array_equal(written.sim.black_box_rad, rig.config.sim.black_box_rad)
    assert written.sim.imu.to_canonical() == rig.config.sim.imu.to_canonical()
    assert written.site.site == rig.config.site.site


def test_the_written_configuration_carries_the_rigs_own_layout(tmp_path):
    # the rig's IMU on its own DBC with its own [imu.signals] (x and y swapped, per-message counter and CRC
    # tables): the written file used to name the DBC only, so `bench run` decoded with the shipped mapping
    dbc = tmp_path / "own_imu.dbc"
    dbc.write_text(DEFAULT_DBC.read_text())
    own = """dbc = "own_imu.dbc"
[imu.signals]
gyro_x = "IMU_GYRO_Y.GyroY"
gyro_y = "IMU_GYRO_X.GyroX"
gyro_z = "IMU_GYRO_Z.GyroZ"
acc_x = "IMU_ACC_Y.AccY"
acc_y = "IMU_ACC_X.AccX"
acc_z = "IMU_ACC_Z.AccZ"
status = "IMU_AUX.Status"
crc = {IMU_GYRO_X = "CRC", IMU_GYRO_Y = "CRC", IMU_GYRO_Z = "CRC", IMU_ACC_X = "CRC", IMU_ACC_Y = "CRC"}
"""
    text = config_text(rate_hz=RATE_HZ).replace("rate_hz = 200.0\n", "rate_hz = 200.0\n" + own, 1)
    (tmp_path / "rig.toml").write_text(text)
    for source in (load_config(tmp_path / "rig.toml"),
                   parse_config(config_text(rate_hz=2000.0).replace("rate_hz =", 'layout = "packed"\nrate_hz ='))):
        with SimRig(source) as own_rig:
            peer = own_rig.serve_socketcand()
            path = tmp_path / "bench.toml"
            path.write_text(rig_config_text(source, "tcp://127.0.0.1:5025", "scpi", peer))
        written = load_config(path)
        assert written.imu.layout.messages == source.imu.layout.messages
        assert written.imu.spec == source.imu.spec and written.imu.layout_name == source.imu.layout_name
    assert 'layout = "packed"' in path.read_text() and "signals" not in path.read_text()


def test_the_rig_serves_and_writes_its_register_map(tmp_path):
    from bench.cli.table import start_listener  # how `bench sim rig` starts its table listener

    register_map = tmp_path / "map.toml"
    register_map.write_text("[modbus]\nunit = 3\nwatchdog_s = 0.0\n[modbus.fault_codes]\n9 = \"coolant\"\n")
    source = parse_config(config_text(dialect="modbus").replace('dialect = "modbus"', 'dialect = "modbus"\n'
                                                                  f'register_map = "{register_map}"'))
    assert source.table.register_map.unit == 3
    closers: list = []
    with SimRig(source) as map_rig:
        try:
            url = start_listener(map_rig.controller, "modbus", "modbus+tcp://127.0.0.1:0", closers,
                                 source.table.register_map)
            path = tmp_path / "bench.toml"
            path.write_text(rig_config_text(source, url, "modbus", map_rig.serve_socketcand()))
            written = load_config(path)
            assert written.table.register_map == source.table.register_map
            table = open_turntable(url, "modbus", register_map=written.table.register_map, timeout_s=2.0)
            table.connect()
            try:                               # unit 3 answers: the simulated controller serves the file's map
                assert len(table.read_state().angles_deg) == 3
            finally:
                table.close()
        finally:
            for close in reversed(closers):
                close()


# -- end to end: `bench sim rig` and `bench run` as two processes -----------------------

RIG_CONFIG = """\
format = "turntable-bench/config"
version = 1
[site]
latitude_deg = 30.27
[table]
url = "sim"
dialect = "{dialect}"
[table.limits.outer]
max_rate_dps = 600.0
max_accel_dps2 = 2400.0
[table.limits.middle]
max_rate_dps = 600.0
max_accel_dps2 = 2400.0
[table.limits.inner]
max_rate_dps = 600.0
max_accel_dps2 = 2400.0
[imu]
interface = "virtual"
channel = "unused"
rate_hz = 100.0
[plan]
positions = "traditional-12"
[sim]
seed = 7
black_box_arcsec = 0.0
noise = true
"""

#: the short plan written into the rig's configuration: traditional-12 + traditional-3s6r, 0.5 s dwells, fast
#: moves and turns (the plan runs in wall-clock time: its length is the test's)
SHORT_PLAN = """\
[plan]
positions = "traditional-12"
rotations = "traditional-3s6r"
dwell_s = 0.5
settle_s = 0.1
rest_s = 0.2
move_rate_dps = 500.0
move_accel_dps2 = 2000.0
turn_rate_dps = 500.0
turn_accel_dps2 = 2000.0

"""
#: a coefficient may miss the truth by this many of its reported sigmas
K_SIGMA = 4.0


def _start_rig(*args: str) -> subprocess.Popen:
    return start_sim("rig", *args)


def _start_rig_writing(tmp_path, dialect: str, *args: str) -> tuple[subprocess.Popen, Path]:
    """A rig of RIG_CONFIG in `dialect` with `args`, writing its bench configuration: (the rig, that file)."""
    rig_config = tmp_path / "rig.toml"
    rig_config.write_text(RIG_CONFIG.format(dialect=dialect))
    written = tmp_path / "bench.toml"
    return _start_rig("--config", str(rig_config), *args, "--write-config", str(written)), written


def _with_plan(text: str, plan: str) -> str:
    start, end = text.index("[plan]"), text.index("[output]")
    return text[:start] + plan + text[end:]


@pytest.mark.slow
@pytest.mark.timeout(240)     # a plan in wall-clock time: ~1 min, the suite's 120 s per test is too tight under load
@pytest.mark.parametrize("dialect, table_listen, imu_listen, url_prefix", [
    ("scpi", "tcp://127.0.0.1:0", "slcan", "tcp://127.0.0.1:"),
    ("modbus", "pty", "socketcand://127.0.0.1:0", "modbus+rtu:///dev/pts/"),
    ("acutrol", "tcp://127.0.0.1:0", "slcan", "tcp://127.0.0.1:"),
    ("acutrol", "pty", "slcan", "/dev/pts/"),
], ids=["scpi-tcp-slcan", "modbus-rtu-pty-socketcand", "acutrol-tcp-slcan", "acutrol-pty-slcan"])
def test_bench_run_against_the_rig_in_another_process_recovers_its_truth(tmp_path, dialect, table_listen, imu_listen,
                                                                         url_prefix):
    rig_config = tmp_path / "rig.toml"
    rig_config.write_text(RIG_CONFIG.format(dialect=dialect))
    written = tmp_path / "bench.toml"
    rig = _start_rig("--config", str(rig_config), "--table-listen", table_listen, "--imu-listen", imu_listen,
                     "--write-config", str(written))
    try:
        startup = read_until(rig, "Ctrl-C stops")
        kind = imu_listen.split(":")[0]
        assert any(f"simulated IMU (100 Hz) on {kind} " in line for line in startup), startup
        written.write_text(_with_plan(written.read_text(), SHORT_PLAN))
        config = load_config(written)
        assert config.imu.interface == kind and config.table.url.startswith(url_prefix)
        assert config.table.dialect == dialect
        out = tmp_path / "runs"
        started = time.monotonic()
        run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out", str(out),
                              "--quiet"], cwd=REPO, capture_output=True, text=True, timeout=200)
        wall_s = time.monotonic() - started
        assert run.returncode == 0, run.stderr
        result = json.loads(only_file(out, "*.result.json").read_text())
        link = result["run"]["imu_link"]
        assert result["run"]["mode"] == "hardware"
        assert link["incomplete_samples"] == link["counter_gaps"] == link["crc_errors"] == link["late"] == 0, link
        truth = {name: entry.to_json()["value"]
                 for name, entry in coefficient_table(config.sim.imu.to_canonical()).items()}
        misses = []
        worst = 0.0
        for name, value in truth.items():
            got = result["coefficients"][name]
            worst = max(worst, abs(got["value"] - value) / got["sigma"])
            if not abs(got["value"] - value) <= K_SIGMA * got["sigma"]:
                misses.append(f"{name}: {got['value']!r} vs {value!r} (sigma {got['sigma']:.3g})")
        assert not misses, misses
        # one time base: the interface's epoch stamps mapped onto the run clock, so the CAN frames, the
        # samples and the table states span the same stretch of time (they were ~1.8e9 s against ~1e4 s)
        log = read_log(only_file(out, "*.mcap"))
        states, frames = log.read_table_states().time_s, log.read_can_timestamps_s()
        assert abs(frames[0] - states[0]) < 30.0 and abs(frames[-1] - states[-1]) < 30.0, (frames[[0, -1]],
                                                                                          states[[0, -1]])
        assert "can_time_offset_s" in log.metadata["imu"] and "can_lag_max_s" in link
        rig.stdin.write("imu status\n")
        rig.stdin.flush()
        status = read_until(rig, "IMU on")[-1]
        assert " 0 dropped" in status, status          # every frame reached bench run
        print(f"e2e: bench run took {wall_s:.1f} s; {link['samples']} samples, {link['frames']} frames; worst "
              f"coefficient {worst:.2f} sigma from the truth; {status}")
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
        assert "stopped" in rig.stderr.read()
    finally:
        stop_process(rig)


@pytest.mark.slow
def test_bench_run_of_a_rig_speaking_another_dialect_suggests_checking_it(tmp_path):
    """Issue 33, item 13: the rig's table speaks MN, the configuration says SCPI: the run stops before anything
    moves, in one line that says to check `[table] dialect` (not only that there was no reply)."""
    rig, written = _start_rig_writing(tmp_path, "mn", "--table-listen", "tcp://127.0.0.1:0", "--imu-listen", "slcan")
    try:
        read_until(rig, "Ctrl-C stops")
        text = _with_plan(written.read_text(), SHORT_PLAN)
        assert 'dialect = "mn"' in text
        written.write_text(text.replace('dialect = "mn"', 'dialect = "scpi"'))
        run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out",
                              str(tmp_path / "runs"), "--quiet", "--no-db"], cwd=REPO, capture_output=True, text=True,
                             timeout=200)
        lines = run.stderr.strip().splitlines()
        assert run.returncode in (2, 3) and len(lines) == 1, run.stderr
        assert "nothing moved" in lines[0] and 'check [table] dialect = "scpi": a controller speaking another ' \
            "dialect (acutrol, mn, modbus)" in lines[0], lines[0]
    finally:
        stop_process(rig)


@pytest.mark.slow
def test_the_rig_serves_the_packed_layout_and_writes_it(tmp_path):
    written = tmp_path / "bench.toml"
    rig = _start_rig("--imu-layout", "packed", "--imu-rate-hz", "2000", "--imu-listen", "socketcand://127.0.0.1:0",
                     "--write-config", str(written))
    try:
        startup = read_until(rig, "Ctrl-C stops")
        assert any("simulated IMU (2000 Hz) on socketcand" in line for line in startup), startup
        config = load_config(written)
        assert config.imu.layout_name == "packed" and config.imu.rate_hz == 2000.0
        with ImuReceiver(config.imu.bus_kwargs(), config.imu.layout, config.imu.rate_hz) as receiver:
            counters = _receive(receiver, 500)
            _assert_no_loss(receiver, counters)
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
    finally:
        stop_process(rig)


@pytest.mark.slow
@pytest.mark.timeout(240)     # the rig and the run in wall-clock time
def test_a_controller_killed_mid_run_is_table_state_unknown_exit_6_never_table_stopped(tmp_path):
    """Issue 34 item 1: the controller's process dies mid-run; no stop can reach it, and the bench says so."""
    rig_config = tmp_path / "rig.toml"
    rig_config.write_text(RIG_CONFIG.format(dialect="scpi"))
    written = tmp_path / "bench.toml"
    rig = _start_rig("--config", str(rig_config), "--table-listen", "tcp://127.0.0.1:0", "--imu-listen",
                     "socketcand://127.0.0.1:0", "--write-config", str(written))
    run = None
    try:
        read_until(rig, "Ctrl-C stops")
        # long dwells: the run is still going when the rig is killed, however fast or slow the machine
        written.write_text(_with_plan(written.read_text(), SHORT_PLAN.replace("dwell_s = 0.5", "dwell_s = 30.0")))
        out = tmp_path / "runs"
        run = subprocess.Popen([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out",
                                str(out), "--quiet"], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
        wait_for(lambda: next((p for p in out.glob("*.mcap") if p.stat().st_size > 100_000), None), 120.0,
                 "the log to pass 100 kB", proc=run)
        rig.kill()                  # the controller's process is gone: its port refuses every connection
        rig.wait(timeout=10)
        _, stderr = run.communicate(timeout=120)
    finally:
        if run is not None:
            stop_process(run)
        stop_process(rig)
    assert run.returncode == 6, stderr
    lines = stderr.strip().splitlines()     # the progress output's FAULT lines (also --quiet), then the end
    assert "Traceback" not in stderr and lines[-1].startswith("bench run: failed: "), stderr
    assert "TABLE STATE UNKNOWN: the controller cannot be reached; stop it at the controller" in lines[-1], stderr
    assert "table stopped" not in stderr and "abort sent" not in stderr, stderr
    log = read_log(only_file(out, "*.mcap"))
    messages = [e.message for e in log.events]
    assert any("TABLE STATE UNKNOWN" in m for m in messages), messages
    assert not any("abort sent" in m or "servos off" in m or m.endswith("table stopped") for m in messages), messages


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGHUP])
def test_the_rig_stops_on_sigint_even_when_ignored_and_on_sighup(signum):
    # a shell starts `bench sim rig ... &` in a script with SIGINT ignored; SIGINT and SIGHUP must still stop it
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "sim", "rig", "--imu-listen",
                             "socketcand://127.0.0.1:0"], cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN))
    try:
        read_until(proc, "Ctrl-C stops")
        proc.send_signal(signum)
        assert proc.wait(timeout=10) == 0
        assert "stopped" in proc.stderr.read()
    finally:
        stop_process(proc)


def test_rig_usage_errors_are_one_line_exit_2(tmp_path):
    code, _, err = cli(["sim", "rig", "--dialect", "scpi", "--register-map", str(tmp_path / "map.toml")])
    assert code == 2 and "--register-map is for the modbus dialect only" in err and len(err.strip().splitlines()) == 1
    # 16-bit whole-count increments at 100 Hz hold 91 deg/s: a 100 deg/s table would saturate every turn
    code, _, err = cli(["sim", "rig", "--imu-layout", "packed", "--imu-rate-hz", "100"])
    assert code == 2 and "beyond the 32,767 that signal GyroX" in err and "at least 110 Hz" in err, err
    assert cli(["sim", "rig", "--imu-listen", "usb0"])[0] == 2
    code, _, err = cli(["sim", "rig", "--table-listen", "tcp://0.0.0.0:0"])
    assert code == 2 and "--allow-remote" in err
    code, _, err = cli(["sim", "rig", "--imu-listen", "socketcand://192.0.2.1:0"])
    assert code == 2 and "--allow-remote" in err
    fd_config = tmp_path / "fd.toml"
    fd_config.write_text(config_text().replace('rate_hz =', 'fd = true\nrate_hz ='))
    code, _, err = cli(["sim", "rig", "--config", str(fd_config), "--imu-listen", "slcan"])
    assert code == 2 and "classic CAN frames only" in err, err
    assert len(err.strip().splitlines()) == 1


def _has_vcan0() -> bool:
    try:
        bus = can.Bus(interface="socketcan", channel="vcan0")
    except Exception:  # noqa: BLE001 - no SocketCAN, no vcan0, no permission: all mean skip
        return False
    bus.shutdown()
    return True


@pytest.mark.skipif(not _has_vcan0(), reason="no SocketCAN interface vcan0 on this host")
def test_python_can_socketcan_client_receives_every_sample_on_vcan0(rig):
    peer = rig.serve_socketcan("vcan0")
    rig.start()
    with ImuReceiver({"interface": "socketcan", "channel": peer.channel}, rig.config.imu.layout, RATE_HZ) as receiver:
        _assert_no_loss(receiver, _receive(receiver, 100))


def test_imu_off_and_on_from_the_console(rig):
    rig.serve_socketcand()
    rig.start()
    assert apply_imu_command(rig, ["off"]) == "ok"
    wait_for(lambda: rig.bus.frames_silenced > 0, 5.0, "the silenced IMU to swallow a frame")
    assert "IMU off" in imu_status(rig)
    assert apply_imu_command(rig, ["on"]) == "ok" and "IMU on" in imu_status(rig)
    assert apply_imu_command(rig, ["drop", "x"]).startswith("error:")
    assert apply_imu_command(rig, ["bogus"]).startswith("unknown imu command")
    for fault in (["corrupt", "2"], ["length"], ["swap"]):
        assert apply_imu_command(rig, fault) == "ok"


@pytest.mark.slow
def test_python_cans_socketcand_warnings_about_reads_that_end_inside_a_frame_are_silenced(caplog):
    # python-can's client reads 1024 bytes at a time and logs a warning each time a read ends inside a
    # `< frame >` element: on any TCP stream with a backlog (a busy client), not a framing fault of the
    # server. The bench opened such a bus and printed "Got incomplete message" lines on stderr in runs.
    logger = logging.getLogger(SOCKETCAND_LOGGER)
    logger.removeFilter(INCOMPLETE_READ_FILTER)
    config = parse_config(config_text(rate_hz=2000.0))
    with SimRig(config) as fast_rig:
        peer = fast_rig.serve_socketcand()
        fast_rig.start()
        kwargs = {"interface": "socketcand", "channel": "can0", **peer.bus_options}
        for silenced in (False, True):
            caplog.clear()
            bus = open_bus(kwargs) if silenced else can.Bus(**kwargs)
            with ImuReceiver(bus, config.imu.layout, 2000.0) as receiver:
                time.sleep(0.5)                 # a busy client: frames pile up in the socket
                counters = _receive(receiver, 2000)
                _assert_no_loss(receiver, counters)
            bus.shutdown()
            warnings = [r for r in caplog.records if r.getMessage().startswith("Got incomplete message")]
            if silenced:
                assert not warnings and INCOMPLETE_READ_FILTER.dropped > 0
            else:
                assert warnings                 # what python-can's client says on its own


def test_a_rig_of_too_few_or_too_many_imus_is_refused_in_one_line():
    """(Several units over SLCAN are served now, a pty per bus: tests/protocol/test_sim_rig_units.py.)"""
    for imus in ("0", "17"):
        rc, _, err = cli(["sim", "rig", "--imus", imus, "--imu-listen", "socketcand://127.0.0.1:0"])
        assert rc == 2 and err.count("\n") == 1 and f"--imus must be 1..16, not {imus}" in err
