"""`bench sim rig --imus N --buses B` against `bench run` in another process: several units on several buses.

Over SLCAN each bus is one simulated adapter (one pty) that the units on it share: the bench opens each pty once and
hands each unit the frames of its own ids. Over socketcand the units of one bus share one connection. Each unit gets
its own result, its truth within its sigmas, and its log topic holds its own frames only. Loopback and ptys only;
every wait is bounded; the short plan runs in wall-clock time (~1 min), so the end-to-end tests are slow.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import numpy as np
import pytest

from bench.config.load import load_config, parse_config
from bench.log.reader import read_log
from bench.model.result import coefficient_table
from bench.sim.rig import SimRig, apply_imu_command, imu_status, rig_config_text, rig_units
from bench.sim.units import unit_truth
from drivers.imu.receiver import ImuReceiver, open_bus
from drivers.imu.shared_bus import SharedBus
from tests.helpers.run import REPO, cli, config_text, only_file, stop_process, wait_for
from tests.helpers.sim_process import read_until
from tests.protocol.test_sim_rig import K_SIGMA, SHORT_PLAN, _assert_no_loss, _receive, _start_rig_writing, _with_plan


def test_rig_units_lay_out_the_buses_as_the_example_configuration():
    """Four units on two buses as multi-imu.example.toml: two per bus, ids +0 and +16, faces z-up and x-up."""
    assert [(u.serial, u.bus, u.id_offset, u.face) for u in rig_units(4, 2)] == [
        ("RIG-0001", 0, 0, "z-up"), ("RIG-0002", 0, 16, "x-up"), ("RIG-0003", 1, 0, "z-up"),
        ("RIG-0004", 1, 16, "x-up")]
    assert [u.bus for u in rig_units(5, 2)] == [0, 0, 0, 1, 1] and [u.bus for u in rig_units(3, 3)] == [0, 1, 2]
    assert [(u.id_offset, u.face) for u in rig_units(3, 1)] == [(0, "z-up"), (16, "x-up"), (32, "y-up")]
    with pytest.raises(ValueError, match="1..2 buses"):
        rig_units(2, 3)


def _two_bus_rig() -> SimRig:
    """A SimRig of the configuration `bench sim rig --imus 4 --buses 2` builds (its placeholder buses)."""
    from bench.sim.rig import RigPeer

    base = parse_config(config_text(rate_hz=100.0, noise="true"))
    placeholders = [RigPeer("virtual", "", "virtual", f"turntable-bench-rig-{b}", {}, bus=b) for b in range(2)]
    return SimRig(parse_config(rig_config_text(base, "sim", "scpi", placeholders, imus=4, buses=2)))


def test_one_slcan_pty_per_bus_read_once_by_the_units_on_it():
    """Two ptys for two buses; on each, the bench's one bulk reader shared by the two units: each unit's receiver
    gets exactly its own ids, every sample, none lost."""
    with _two_bus_rig() as rig:
        assert len(rig.buses) == 2
        peers = [rig.serve_slcan(b) for b in range(2)]
        assert peers[0].channel != peers[1].channel and [p.bus for p in peers] == [0, 1]
        rig.start()
        config = parse_config(rig_config_text(rig.config, "tcp://127.0.0.1:5025", "scpi", peers, imus=4, buses=2))
        assert [u.channel for u in config.units] == [peers[0].channel] * 2 + [peers[1].channel] * 2
        shared = [SharedBus(open_bus({**config.units[2 * b].bus_kwargs(), "sleep_after_open": 0}))
                  for b in range(2)]
        try:
            receivers = [ImuReceiver(shared[k // 2].view(unit.layout.keys), unit.layout, unit.rate_hz)
                         for k, unit in enumerate(config.units)]
            for receiver in receivers:
                _assert_no_loss(receiver, _receive(receiver, 60))
                assert receiver.stats.unknown_id == 0, receiver.stats      # only its own ids reached it
            assert [rig.server(b).clients for b in range(2)] == [1, 1]      # each pty opened once
            assert apply_imu_command(rig, ["off"]) == "ok"                  # every bus falls silent
            wait_for(lambda: all(bus.frames_silenced for bus in rig.buses), 5.0, "both buses to swallow a frame")
            assert imu_status(rig).startswith("IMU off") and "(bus 2)" in imu_status(rig)
        finally:
            for bus in shared:
                bus.shutdown()


def test_rig_usage_errors_of_several_buses_are_one_line_exit_2():
    for args, said in ((["--imus", "2", "--buses", "3"], "--buses must be 1..2 (the --imus units), not 3"),
                       (["--imus", "2", "--buses", "2", "--imu-listen", "socketcand://127.0.0.1:29536"],
                        "with 2 buses socketcand listens on port 0"),
                       (["--imus", "2", "--buses", "2", "--imu-listen", "socketcan:vcan0"],
                        "names 1 SocketCAN channel(s) for 2 bus(es)")):
        rc, _, err = cli(["sim", "rig", *args])
        assert rc == 2 and err.count("\n") == 1 and said in err, (args, err)


def _run_against(tmp_path, *rig_args: str, expect_units: list[tuple[str, str, int, str]]) -> None:
    """Start `bench sim rig` with `rig_args`, run `bench run` of its written configuration with the short plan, and
    check every unit (`expect_units`: serial, face, id offset and the start of its channel): its own result, truth
    within K_SIGMA sigmas, no sample lost, its log topic its own ids only."""
    rig, written = _start_rig_writing(tmp_path, "scpi", *rig_args)
    try:
        read_until(rig, "Ctrl-C stops")
        written.write_text(_with_plan(written.read_text(), SHORT_PLAN))
        config = load_config(written)
        got = [(u.identity.serial, u.mounting_name, u.id_offset, str(u.channel)) for u in config.units]
        assert len(got) == len(expect_units) and all(
            g[:3] == e[:3] and g[3].startswith(e[3]) for g, e in zip(got, expect_units)), got
        out = tmp_path / "runs"
        run = subprocess.run([sys.executable, "-m", "bench.cli", "run", "--config", str(written), "--out", str(out),
                              "--quiet", "--no-db"], cwd=REPO, capture_output=True, text=True, timeout=200)
        assert run.returncode == 0, run.stderr
        log_path = only_file(out, "*.mcap")
        for k, unit in enumerate(config.units):
            result = json.loads(only_file(out, f"*.{unit.identity.serial}.result.json").read_text())
            assert result["run"]["imu"]["serial"] == unit.identity.serial and result["run"]["mode"] == "hardware"
            link = result["run"]["imu_link"]
            assert link["samples"] > 0 and link["incomplete_samples"] == link["counter_gaps"] == 0, link
            assert link["crc_errors"] == link["late"] == link["duplicates"] == 0, link
            truth = {name: entry.to_json()["value"] for name, entry in coefficient_table(
                unit_truth(config.sim.imu, k, config.sim.seed).to_canonical()).items()}
            misses = [f"{unit.identity.serial} {name}: {result['coefficients'][name]['value']!r} vs {value!r}"
                      for name, value in truth.items()
                      if not abs(result["coefficients"][name]["value"] - value)
                      <= K_SIGMA * result["coefficients"][name]["sigma"]]
            assert not misses, misses
            if k:    # another unit's topic: its own frames only (the reference unit's /can/raw is its bus)
                ids = read_log(log_path, unit=unit.identity.serial).read_can_frames().ids
                own = np.array(sorted(unit.layout.keys))
                assert len(ids) and np.isin(ids, own).all(), np.unique(ids)
                assert link["unknown_id"] == 0, link
        rig.stdin.write("imu status\n")
        rig.stdin.flush()
        status = read_until(rig, "IMU on")[-1]
        assert status.count(" 0 dropped") == len(set(str(u.channel) + str(u.bus_options) for u in config.units)), \
            status
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
    finally:
        stop_process(rig)


@pytest.mark.slow
@pytest.mark.timeout(240)     # a plan in wall-clock time: ~1 min
def test_bench_run_against_two_imus_on_two_slcan_buses(tmp_path):
    """`bench sim rig --imus 2 --buses 2` over SLCAN: a pty per bus, each unit on its own."""
    _run_against(tmp_path, "--imu-listen", "slcan", "--imus", "2", "--buses", "2",
                 expect_units=[("RIG-0001", "z-up", 0, "/dev/pts/"), ("RIG-0002", "z-up", 0, "/dev/pts/")])


@pytest.mark.slow
@pytest.mark.timeout(240)     # a plan in wall-clock time: ~1 min
def test_bench_run_against_two_imus_sharing_one_socketcand_bus(tmp_path):
    """`bench sim rig --imus 2` over socketcand: two units on one bus (ids offset 16, faces z-up and x-up) read
    through one connection, each unit its own frames and result."""
    _run_against(tmp_path, "--imu-listen", "socketcand://127.0.0.1:0", "--imus", "2",
                 expect_units=[("RIG-0001", "z-up", 0, "can0"), ("RIG-0002", "x-up", 16, "can0")])
