"""`bench chamber` against `bench sim chamber` and `bench sim rig --chamber-...` in another process (TCP and a pty,
both dialects), the consoles' alarms and wire faults, and one-line usage errors with exit 2."""

from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from bench.config.load import load_config
from tests.helpers.run import REPO, cli, config_text, stop_process
from tests.helpers.sim_process import read_until, start_sim


def _console(proc: subprocess.Popen, line: str, marker: str) -> str:
    proc.stdin.write(line + "\n")
    proc.stdin.flush()
    return read_until(proc, marker)[-1]


@pytest.mark.slow
@pytest.mark.parametrize("dialect, listen, prefix", [
    ("ascii", "tcp://127.0.0.1:0", "tcp://127.0.0.1:"),
    ("ascii", "pty", "/dev/pts/"),
    ("modbus", "modbus+tcp://127.0.0.1:0", "modbus+tcp://127.0.0.1:"),
    ("modbus", "pty", "modbus+rtu:///dev/pts/"),
])
def test_bench_chamber_drives_the_served_simulator(dialect, listen, prefix):
    proc = start_sim("chamber", "--dialect", dialect, "--listen", listen)
    try:
        line = read_until(proc, "listening on")[-1]
        url = line.split("listening on ")[1].strip()
        assert url.startswith(prefix), url
        read_until(proc, "Ctrl-C stops")
        base = ["chamber", "--url", url, "--dialect", dialect, "--timeout-s", "0.5"]
        code, out, err = cli([*base, "set", "-20", "--ramp-c-per-min", "2", "--run"])
        assert code == 0, err
        assert "setpoint     -20.0 degC" in out and "mode         running" in out and "2 degC/min" in out
        assert "setpoint -20.0 degC, ramp 2 degC/min, running" in _console(proc, "state", "setpoint")
        code, out, err = cli([*base, "set", "99"])                      # beyond the default limits: nothing sent
        assert code == 2 and "refused, nothing sent" in err and len(err.strip().splitlines()) == 1
        # an alarm every dialect names (the F4P's map: the input 1 error register; it has none for a door)
        assert _console(proc, "alarm sensor_fault", "ok").strip() == "ok"
        code, out, err = cli([*base, "status"])
        assert code == 3 and "sensor fault" in out and "mode         stopped" in out
        code, _, err = cli([*base, "run"])
        assert code == 3 and "ChamberAlarm" in err and "chamber: stopped" in err
        code, out, _ = cli([*base, "clear"])
        assert code == 0 and "alarms       none" in out
        _console(proc, "garbage 3", "ok")
        code, _, err = cli([*base, "--retries", "2", "status"])
        if dialect == "modbus":     # the F4P's map reads its settings at connect: the garbage meets that read
            assert code == 2 and "cannot reach the chamber: read settings" in err and "garbage" in err, err
        else:
            assert code == 3 and "ChamberProtocolError" in err and "chamber: stopped" in err, err
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=10) == 0
        assert "stopped" in proc.stderr.read()
    finally:
        stop_process(proc)


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_the_rig_serves_a_chamber_and_writes_its_section(tmp_path):
    written = tmp_path / "bench.toml"
    rig = start_sim("rig", "--imu-listen", "socketcand://127.0.0.1:0", "--chamber-dialect", "modbus",
                 "--write-config", str(written))
    try:
        startup = read_until(rig, "Ctrl-C stops")
        assert any("simulated chamber (modbus) listening on modbus+tcp://127.0.0.1:" in line for line in startup)
        chamber = load_config(written).chamber
        assert chamber is not None and chamber.dialect == "modbus" and chamber.safe_setpoint_c == 23.0
        code, out, err = cli(["chamber", "--config", str(written), "set", "40", "--run"])
        assert code == 0 and "setpoint     40.0 degC" in out, err
        assert "alarm" in _console(rig, "chamber help", "alarm over_temperature")
        assert _console(rig, "chamber alarm equipment_fault", "ok").strip() == "ok"
        code, _, err = cli(["chamber", "--config", str(written), "run"])
        # the safe setpoint is refused too while the alarm is latched; the stop still goes out
        assert code == 3 and "equipment fault" in err and "stopped" in err, err
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
    finally:
        stop_process(rig)


def test_usage_errors_are_one_line_exit_2(tmp_path):
    no_chamber = tmp_path / "plain.toml"
    no_chamber.write_text(config_text())
    sim_chamber = tmp_path / "sim.toml"
    sim_chamber.write_text(config_text() + '\n[chamber]\nurl = "sim"\ndialect = "ascii"\n')
    bad = tmp_path / "bad.toml"
    bad.write_text(config_text() + '\n[chamber]\nurl = "sim"\ndialect = "espec"\n')
    f4_map = tmp_path / "f4.toml"            # set point 1 by its 40001-based number: not a relative one
    f4_map.write_text("[modbus]\nunit = 1\n[modbus.registers]\nsetpoint = 40301\n")
    for argv, words in (
            (["chamber", "--url", "modbus+tcp://127.0.0.1:9", "--register-map", str(f4_map), "status"],
             f"{f4_map}:4: modbus.registers.setpoint: the Watlow F4P has no register 40301"),
            (["sim", "chamber", "--dialect", "modbus", "--register-map", "watlow-f5", "--listen", "pty"],
             "no register map preset or file 'watlow-f5' (presets: watlow-f4, generic)"),
            (["sim", "chamber", "--dialect", "ascii", "--register-map", "generic", "--listen", "pty"],
             "modbus dialect only"),
            (["chamber", "--url", "tcp://127.0.0.1:9", "status"], "say which dialect"),
            (["chamber", "--url", "tcp://127.0.0.1:9", "--dialect", "ascii", "--register-map", "m.toml", "status"],
             "modbus dialect only"),
            (["chamber", "--url", "tcp://127.0.0.1:9", "--dialect", "modbus", "status"], "needs a modbus"),
            (["chamber", "--config", str(no_chamber), "status"], "no [chamber] section"),
            (["chamber", "--config", str(sim_chamber), "status"], "bench sim chamber"),
            (["chamber", "--config", str(bad), "status"], "bad.toml:"),
            (["chamber", "--url", "tcp://127.0.0.1:9", "--dialect", "ascii", "--min-setpoint-c", "90", "status"],
             "min_setpoint_c must be below"),
            (["sim", "chamber", "--dialect", "ascii", "--listen", "tcp://0.0.0.0:0"], "--allow-remote"),
            (["sim", "chamber", "--dialect", "modbus", "--listen", "tcp://127.0.0.1:0"], "modbus+tcp://HOST:PORT"),
            (["sim", "chamber", "--dialect", "ascii", "--listen", "pty", "--time-constant-s", "0"],
             "time_constant_s")):
        code, _, err = cli(argv)
        assert code == 2 and words in err and len(err.strip().splitlines()) == 1, (argv, err)


@pytest.mark.slow
def test_the_simulator_serves_the_generic_map_on_request():
    proc = start_sim("chamber", "--dialect", "modbus", "--register-map", "generic", "--listen",
                     "modbus+tcp://127.0.0.1:0")
    try:
        url = read_until(proc, "listening on")[-1].split("listening on ")[1].strip()
        read_until(proc, "Ctrl-C stops")
        code, out, err = cli(["chamber", "--url", url, "--register-map", "generic", "--timeout-s", "0.5", "status"])
        assert code == 0 and "temperature  23.0 degC" in out, err
        # the default map is the F4P's: its settings registers (602-606) are not served by the generic map
        code, _, err = cli(["chamber", "--url", url, "--timeout-s", "0.5", "status"])
        assert code == 2 and "cannot reach the chamber: read settings" in err and "illegal data address" in err, err
    finally:
        stop_process(proc)


def test_an_unreachable_chamber_is_exit_2_nothing_sent():
    code, _, err = cli(["chamber", "--url", "tcp://127.0.0.1:9", "--dialect", "ascii", "status"])
    assert code == 2 and "cannot reach the chamber" in err and "nothing sent" in err


@pytest.mark.slow
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_a_stop_signal_while_waiting_for_the_chamber_makes_it_safe(signum):
    from bench.sim.chamber import SimChamber
    from bench.sim.chamber_server import serve_chamber
    from tests.helpers.run import wait_for

    sim = SimChamber()
    sim.set_setpoint(40.0)
    sim.run()
    sim.faults.timeout = 1                       # the status request's reply never comes: the command waits
    close, url = serve_chamber(sim, "ascii")
    proc = subprocess.Popen([sys.executable, "-m", "bench.cli", "chamber", "--url", url, "--dialect", "ascii",
                             "--timeout-s", "60", "--retries", "0", "status"], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: sim.faults.timeout == 0, 30.0, "the status request to arrive", proc=proc)
        proc.send_signal(signum)
        _, stderr = proc.communicate(timeout=30)
        assert proc.returncode == 3, stderr
        name = "Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name
        assert stderr.strip() == f"bench chamber status: interrupted ({name}); chamber: stopped", stderr
        assert not sim.state().running
    finally:
        stop_process(proc)
        close()
