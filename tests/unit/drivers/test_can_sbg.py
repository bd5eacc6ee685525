"""The sbg-ecan layout: SBG Systems' published CAN IMU messages (docs/hardware/can.md, section sbg-ecan).

Frames are written out by hand from the field tables of SBG's CAN protocol document (sbgECom
doc/canProtocol.md, "Inertial Data Output Messages": SBG_ECAN_MSG_IMU_INFO 0x120, _IMU_ACCEL 0x121,
_IMU_GYRO 0x122; little-endian, scale 1 us / 10^-2 degC / 10^-2 m/s^2 / 10^-3 rad/s) and checked against
our decoders, our encoder and cantools reading our DBC. In-process virtual buses only.
"""

from __future__ import annotations

import itertools
import re
import signal

import can
import cantools
import numpy as np
import pytest

from bench.config.load import ConfigError, load_config, parse_config
from bench.model.imu import NoiseModel, default_sim_si_imu
from bench.model.observations import rounding_bias_variance
from bench.run.runner import compile_from_config
from bench.sim.can_imu import SimCanImu
from bench.sim.imu import SimImu
from bench.sim.rig import imu_layout_lines
from bench.sim.table import SimTable
from drivers.imu import SHIPPED_LAYOUTS, ImuEncoder, decode_frames, frames_from_messages
from drivers.imu.layout import SBG_ECAN_DBC, describe_status, sbg_ecan_layout
from drivers.imu.receiver import ImuReceiver
from drivers.imu.stream import StreamDecoder
from tests.helpers.run import (
    Trigger,
    api_run,
    cli,
    config_text,
    load_json,
    only_file,
    step_index,
    stop_process,
    values,
)
from tests.helpers.sim_process import read_until, start_sim

RATE_HZ = 200.0
INFO, ACCEL, GYRO = 0x120, 0x121, 0x122

# One sample as the document's tables define it, bytes written out by hand:
# IMU_INFO: TIME_STAMP uint32 us at 0 = 125000 (0x0001E848), IMU_STATUS uint16 at 4 = 0x03FF (all ten health
# bits), TEMPERATURE int16 at 6, 10^-2 degC = 23.45 (2345 = 0x0929)
INFO_BYTES = bytes.fromhex("48E80100" "FF03" "2909")
# IMU_ACCEL: ACCEL_X/Y/Z int16, 10^-2 m/s^2 = 9.81 (981 = 0x03D5), -0.05 (-5 = 0xFFFB), -9.80 (-980 = 0xFC2C)
ACCEL_BYTES = bytes.fromhex("D503" "FBFF" "2CFC")
# IMU_GYRO: GYRO_X/Y/Z int16, 10^-3 rad/s = 0.175 (175 = 0x00AF), -0.001 (0xFFFF), 32.767 (0x7FFF, the top)
GYRO_BYTES = bytes.fromhex("AF00" "FFFF" "FF7F")
ACCEL_MPS2 = [9.81, -0.05, -9.80]
GYRO_RADPS = [0.175, -0.001, 32.767]

_channels = itertools.count()


def _sample(timestamp_us: int) -> list[tuple[int, bytes]]:
    return [(INFO, timestamp_us.to_bytes(4, "little") + INFO_BYTES[4:]), (ACCEL, ACCEL_BYTES), (GYRO, GYRO_BYTES)]


def _arrays(frames: list[tuple[int, bytes]]):
    ids = np.array([k for k, _ in frames], np.int64)
    data = np.zeros((len(frames), 8), np.uint8)
    for i, (_, payload) in enumerate(frames):
        data[i, :len(payload)] = np.frombuffer(payload, np.uint8)
    return ids, data, np.array([len(p) for _, p in frames], np.int64), np.arange(len(frames), dtype=float)


def _all_decoders(frames: list[tuple[int, bytes]], cut: int = 4):
    """(block, stats) of the stream decoder fed live (a frame at a time), the bulk decoder and the stream
    decoder in pieces of `cut`: asserted identical, returned once."""
    layout = sbg_ecan_layout()
    live = StreamDecoder(layout, RATE_HZ)
    one_by_one = _arrays(frames)
    for i in range(len(frames)):
        live.feed(*(a[i:i + 1] for a in one_by_one))
    live_block, _ = live.finish()
    bulk_block, bulk_stats = decode_frames(*_arrays(frames), layout=layout, rate_hz=RATE_HZ)
    stream = StreamDecoder(layout, RATE_HZ)
    ids, data, lengths, times = _arrays(frames)
    for a in range(0, len(frames), cut):
        stream.feed(ids[a:a + cut], data[a:a + cut], lengths[a:a + cut], times[a:a + cut])
    stream_block, stream_stats = stream.finish()
    assert live.stats == bulk_stats == stream_stats
    for block in (live_block, stream_block):
        assert np.array_equal(block.counter, bulk_block.counter)
        assert np.array_equal(block.gyro_counts, bulk_block.gyro_counts)
        assert np.array_equal(block.acc_counts, bulk_block.acc_counts)
        assert np.array_equal(block.status, bulk_block.status)
    return bulk_block, bulk_stats


# -- the layout and the hand-written frames --------------------------------------------------------

def test_the_layout_is_the_documented_messages_ids_types_and_scales():
    layout = sbg_ecan_layout()
    assert [(m.name, m.frame_id, m.length, m.is_extended_id) for m in layout.messages] == [
        ("IMU_INFO", 0x120, 8, False), ("IMU_ACCEL", 0x121, 6, False), ("IMU_GYRO", 0x122, 6, False)]
    assert layout.scale == (0.001, 0.001, 0.001, 0.01, 0.01, 0.01, 0.01, 1.0)
    assert layout.time_stamp is not None and layout.time_stamp.signal.length == 32
    assert not layout.time_stamp.signal.signed and layout.time_stamp.unit_s == 1e-6
    assert layout.status_required == 0x03FF and layout.status_invalid == 0
    assert all(m.crc_byte is None for m in layout.messages)
    db = cantools.database.load_file(SBG_ECAN_DBC)
    for message in db.messages:
        assert all(s.byte_order == "little_endian" for s in message.signals)
    assert {s.name: (s.length, s.is_signed, s.scale, s.unit) for s in db.get_message_by_name("IMU_INFO").signals} == {
        "TimeStamp": (32, False, 1, "us"), "ImuStatus": (16, False, 1, None), "Temperature": (16, True, 0.01, "degC")}
    assert "sbg-ecan" in SHIPPED_LAYOUTS


def test_hand_written_frames_decode_to_the_documented_values():
    block, stats = _all_decoders(_sample(125000))
    assert stats.samples == 1 and stats.frame_faults == 0
    assert block.gyro_rate[0] == pytest.approx(GYRO_RADPS, abs=1e-12)
    assert block.acc_rate[0] == pytest.approx(ACCEL_MPS2, abs=1e-12)
    assert block.temperature_c[0] == pytest.approx(23.45) and block.status[0] == 0x03FF
    assert block.counter[0] == 25 and block.time_s[0] == pytest.approx(0.125)   # 125000 us at 200 Hz


def test_cantools_reads_the_hand_written_frames_as_the_document_says():
    db = cantools.database.load_file(SBG_ECAN_DBC)
    assert db.decode_message(INFO, INFO_BYTES) == pytest.approx(
        {"TimeStamp": 125000, "ImuStatus": 0x03FF, "Temperature": 23.45})
    assert db.decode_message(ACCEL, ACCEL_BYTES) == pytest.approx(dict(zip(("AccelX", "AccelY", "AccelZ"),
                                                                           ACCEL_MPS2)))
    assert db.decode_message(GYRO, GYRO_BYTES) == pytest.approx(dict(zip(("GyroX", "GyroY", "GyroZ"), GYRO_RADPS)))


def test_the_encoder_writes_the_hand_written_bytes():
    encoder = ImuEncoder(sbg_ecan_layout(), rate_hz=RATE_HZ)
    frames = encoder.encode([25], np.array([GYRO_RADPS]) / RATE_HZ, np.array([ACCEL_MPS2]) / RATE_HZ, 23.45)
    assert [frames.frame(i) for i in range(3)] == _sample(125000)


def test_the_encoder_rounds_each_sample_on_its_own_and_saturates_clearing_the_in_range_bit():
    encoder = ImuEncoder(sbg_ecan_layout(), saturate=True, rate_hz=RATE_HZ)
    rates = np.array([[0.0004, 0.0006, 40.0]] * 2)   # the same rate twice: no remainder carried between samples
    frames = encoder.encode([0, 1], rates / RATE_HZ, np.zeros((2, 3)))
    gyro = [frames.frame(i)[1] for i in (2, 5)]
    assert gyro[0] == gyro[1] == bytes.fromhex("0000" "0100" "FF7F")
    assert frames.frame(0)[1][4:6] == (0x03FF & ~(1 << 9)).to_bytes(2, "little")   # gyros not within range
    with pytest.raises(Exception, match="rate_hz"):
        ImuEncoder(sbg_ecan_layout())


# -- the assembly rule ------------------------------------------------------------------------------

def test_consecutive_samples_number_by_their_time_stamps_across_the_32_bit_wrap():
    top = 2 ** 32 - 5000                # the last sample before the wrap, then 0 and 5000 us after it
    frames = _sample(top - 5000) + _sample(top) + _sample((top + 5000) % 2 ** 32) + _sample((top + 10000) % 2 ** 32)
    block, stats = _all_decoders(frames)
    assert stats.samples == 4 and stats.counter_gaps == 0
    assert np.array_equal(np.diff(block.counter), [1, 1, 1])


def test_time_stamps_that_jitter_around_any_phase_number_consecutively():
    jitter = [0, 37, -41, 12, -3, 44, -44, 9]
    frames = [f for n, j in enumerate(jitter) for f in _sample(2500 + 5000 * n + j)]   # half a period off the grid
    block, stats = _all_decoders(frames)
    assert stats.samples == len(jitter) and stats.counter_gaps == stats.duplicates == 0
    assert list(block.counter) == list(range(len(jitter)))


def test_a_time_stamp_gap_is_counted_as_missing_samples():
    frames = _sample(0) + _sample(5000) + _sample(20000)    # 10000 and 15000 us never came
    block, stats = _all_decoders(frames)
    assert stats.samples == 3 and stats.counter_gaps == 2
    assert list(block.counter) == [0, 1, 4]


def test_data_frames_before_the_first_time_stamp_are_late_and_a_lost_gyro_frame_is_an_incomplete_sample():
    frames = [(ACCEL, ACCEL_BYTES), (GYRO, GYRO_BYTES)] + _sample(5000) + _sample(10000)[:2] + _sample(15000)
    block, stats = _all_decoders(frames)
    assert stats.late == 2 and stats.incomplete_samples == 1 and stats.samples == 2
    assert stats.frames == len(frames) == stats.frames_ok + stats.frame_faults
    assert list(block.counter) == [1, 3]


def test_a_lost_time_stamp_frame_leaves_its_data_frames_as_duplicates_of_the_sample_before():
    frames = _sample(0) + _sample(5000)[1:] + _sample(10000)
    block, stats = _all_decoders(frames)
    assert stats.duplicates == 2 and stats.samples == 2 and stats.counter_gaps == 1
    assert list(block.counter) == [0, 2]


def test_a_short_frame_is_counted_wrong_length():
    frames = _sample(0) + [(INFO, _sample(5000)[0][1]), (ACCEL, ACCEL_BYTES[:5]), (GYRO, GYRO_BYTES)] + _sample(10000)
    _, stats = _all_decoders(frames)
    assert stats.wrong_length == 1 and stats.incomplete_samples == 1 and stats.samples == 2


def test_random_faulty_streams_decode_alike_live_bulk_and_in_pieces():
    rng = np.random.default_rng(5)
    frames = [f for n in range(300) for f in _sample((n * 5000 + 7) % 2 ** 32)]
    keep = [f for f in frames if rng.random() > 0.05]
    for i in rng.integers(0, len(keep) - 1, 10):          # some swapped neighbours
        keep[i], keep[i + 1] = keep[i + 1], keep[i]
    keep += [(0x7FF, b"\x01\x02")]
    for cut in (1, 7, 50):
        _, stats = _all_decoders(keep, cut)
    assert stats.unknown_id == 1 and stats.samples > 200


# -- the simulator on a bus, read back by cantools with our DBC ----------------------------------

def test_cantools_decodes_the_simulators_frames_as_our_decoder_does():
    channel = f"test_can_sbg_{next(_channels)}"
    tx, rx = can.Bus(interface="virtual", channel=channel), can.Bus(interface="virtual", channel=channel)
    try:
        table = SimTable()
        table.move_to(0.0, (30.0, -20.0, 10.0), rate_dps=20.0, accel_dps2=40.0)
        table.turn(0.5, "inner", "ccw", 1, 30.0, 60.0)
        imu = SimImu(default_sim_si_imu(), NoiseModel.mems(), rate_hz=RATE_HZ, seed=3)
        sim = SimCanImu(table, imu, tx, sbg_ecan_layout())
        sim.step_to(3.0)
        messages = [m for m in iter(lambda: rx.recv(timeout=0.0), None)]
    finally:
        tx.shutdown()
        rx.shutdown()
    assert len(messages) == 3 * 600
    block, stats = decode_frames(*frames_from_messages(messages), layout=sbg_ecan_layout(), rate_hz=RATE_HZ)
    assert stats.samples == 600 and stats.frame_faults == 0
    db = cantools.database.load_file(SBG_ECAN_DBC)
    decoded = [db.decode_message(m.arbitration_id, m.data) for m in messages]
    info, accel, gyro = decoded[0::3], decoded[1::3], decoded[2::3]
    assert [d["TimeStamp"] for d in info] == [round(c * 1e6 / RATE_HZ) for c in block.counter]
    assert np.allclose([[d[f"Gyro{a}"] for a in "XYZ"] for d in gyro], block.gyro_rate, rtol=0, atol=1e-12)
    assert np.allclose([[d[f"Accel{a}"] for a in "XYZ"] for d in accel], block.acc_rate, rtol=0, atol=1e-12)
    assert np.allclose([d["Temperature"] for d in info], block.temperature_c, atol=1e-12)
    assert [d["ImuStatus"] for d in info] == list(block.status) == [0x03FF] * 600
    assert np.abs(block.gyro_rate).max() > 0.4       # the turn is in the frames (30 deg/s)


# -- configuration and the solve's view of the status and the resolution ---------------------------------

def test_the_config_selects_the_layout_and_the_simulated_mems_imu():
    text = config_text(noise="true").replace('[imu]\n', '[imu]\nlayout = "sbg-ecan"\n')
    config = parse_config(text)
    assert config.imu.layout_name == "sbg-ecan" and config.imu.layout.time_stamp is not None
    assert config.sim.noise == NoiseModel.mems()
    assert config.sim.imu.to_canonical() == default_sim_si_imu().to_canonical()
    with pytest.raises(ConfigError, match="sim.noise.quantise.*physical units"):
        parse_config(text.replace("noise = true", "noise = { enabled = true, quantise = true }"))


def test_missing_health_bits_are_named():
    assert describe_status(1 << 9, 0, 0x03FF) == "gyros-in-range clear"
    assert describe_status(0b11, 0, 0x03FF) == "com-ok clear, built-in-test-ok clear"


def test_the_rounding_that_noise_does_not_dither_away():
    step = np.array([0.001])
    assert rounding_bias_variance(np.array([0.0]), step)[0] == pytest.approx(0.001 ** 2 / 12, rel=1e-3)
    # noise of half a step leaves ~0.6 % of the step in a long average; of one step, nothing measurable
    half = np.sqrt(rounding_bias_variance(np.sqrt([0.5 ** 2 * 1e-6 + 1e-6 / 12]), step)[0]) / 0.001
    assert 1e-3 < half < 1e-2
    assert rounding_bias_variance(np.sqrt([1e-6 + 1e-6 / 12]), step)[0] < 1e-12 * 1e-6


# -- a whole run ---------------------------------------------------------------------------------------

@pytest.mark.slow
def test_bench_run_sim_with_the_sbg_layout_recovers_the_truth_within_its_budget(tmp_path):
    """`bench run --sim` on the short plan (3 s dwells, 200 Hz) with the MEMS IMU the layout simulates: exit 0 and
    every coefficient within 3 sigma of the truth (the noise-on standard of tests/e2e/test_run.py), the resolution in
    the budget of the turns, the uncertainties not inflated."""
    config = tmp_path / "bench.toml"
    config.write_text(config_text(noise="true", rate_hz=RATE_HZ).replace("[imu]\n", '[imu]\nlayout = "sbg-ecan"\n'))
    rc, _, stderr = cli(["run", "--sim", "--config", str(config), "--out", str(tmp_path / "out"), "--quiet",
                         "--no-db"])
    assert rc == 0, stderr
    result = load_json(only_file(tmp_path / "out", "*.result.json"))
    coefficients, truth = result["coefficients"], values(result, "sim_truth")
    z = {name: (coefficients[name]["value"] - truth[name]) / coefficients[name]["sigma"] for name in truth}
    assert all(abs(v) <= 3.0 for v in z.values()), {k: round(v, 2) for k, v in z.items() if abs(v) > 3.0}
    assert 0.3 < float(np.sqrt(np.mean(np.square(list(z.values()))))) < 2.0, z
    assert all("count resolution" in coefficients[f"Kg_{s}"]["budget"] for s in "xyz")
    assert result["quality"]["uncertainty"]["inputs"]["count_resolution"] == 0.0
    assert not any("dither" in flag for flag in result["quality"]["flags"]), result["quality"]["flags"]
    outside = sorted(name for name, v in z.items() if abs(v) > coefficients[name]["k"])
    print(f"sbg-ecan run: rms z {np.sqrt(np.mean(np.square(list(z.values())))):.2f}, "
          f"outside U (k = 2): {outside or 'none'}")


@pytest.mark.slow
def test_bench_sim_rig_serves_the_sbg_layout_and_writes_it(tmp_path):
    """`bench sim rig --imu-layout sbg-ecan`: the written configuration selects the layout and the simulated MEMS
    IMU, and python-can's socketcand client receives its frames, decoded with no loss."""
    written = tmp_path / "bench.toml"
    rig = start_sim("rig", "--imu-layout", "sbg-ecan", "--imu-listen", "socketcand://127.0.0.1:0", "--write-config",
                    str(written))
    try:
        startup = read_until(rig, "Ctrl-C stops")
        assert any("simulated IMU (200 Hz) on socketcand" in line for line in startup), startup
        config = load_config(written)
        assert config.imu.layout_name == "sbg-ecan" and config.sim.noise == NoiseModel.mems()
        with ImuReceiver(config.imu.bus_kwargs(), config.imu.layout, config.imu.rate_hz) as receiver:
            counters = []
            for _ in range(2000):                  # bounded: 2000 polls of at most 20 ms
                counters.append(receiver.poll(timeout_s=0.02).counter)
                if sum(map(len, counters)) >= 400:
                    break
            stats = receiver.stats
        got = np.concatenate(counters)
        assert len(got) >= 400 and np.all(np.diff(got) == 1), "a gap in the samples"
        assert stats.frame_faults == stats.incomplete_samples == stats.counter_gaps == 0, stats
        rig.send_signal(signal.SIGTERM)
        assert rig.wait(timeout=10) == 0
    finally:
        stop_process(rig)


def test_an_sbg_imu_configured_with_other_ids_is_read_with_an_edited_copy_of_the_dbc(tmp_path):
    """The device's ids are set per message: a copy of the DBC with them, mapped as the shipped layout is
    (docs/hardware/can.md), decodes at those ids, and the rig writes the mapping back as it read it."""
    text = SBG_ECAN_DBC.read_text()
    for old, new in ((288, 800), (289, 801), (290, 802)):
        text = text.replace(f"BO_ {old} ", f"BO_ {new} ").replace(f"SG_ {old} ", f"SG_ {new} ")
    dbc = tmp_path / "my-sbg.dbc"
    dbc.write_text(text)
    spec = SHIPPED_LAYOUTS["sbg-ecan"][1]
    signals = "".join(f'{c} = "{ref}"\n' for c, ref in spec.channels.items())
    signals += ('temperature = "IMU_INFO.Temperature"\nstatus = "IMU_INFO.ImuStatus"\nstatus_required = 0x3FF\n'
                'time_stamp = "IMU_INFO.TimeStamp"\n')
    config_toml = config_text(rate_hz=RATE_HZ).replace("[imu]\n", f'[imu]\ndbc = "{dbc}"\n').replace(
        "[imu.identity]", f"[imu.signals]\n{signals}[imu.identity]")
    config = parse_config(config_toml)
    layout = config.imu.layout
    assert [m.frame_id for m in layout.messages] == [0x320, 0x321, 0x322] and layout.status_required == 0x3FF
    frames = ImuEncoder(layout, rate_hz=RATE_HZ).encode([25], np.array([GYRO_RADPS]) / RATE_HZ,
                                                        np.array([ACCEL_MPS2]) / RATE_HZ, 23.45)
    assert [frames.frame(i) for i in range(3)] == [(key + 0x200, payload) for key, payload in _sample(125000)]
    block, stats = decode_frames(frames.ids, frames.data, frames.lengths, layout=layout, rate_hz=RATE_HZ)
    assert stats.samples == 1 and block.gyro_rate[0] == pytest.approx(GYRO_RADPS)
    rewritten = config_toml.replace(f'dbc = "{dbc}"\n', "\n".join(imu_layout_lines(config.imu)) + "\n")
    rewritten = rewritten[:rewritten.index("[imu.signals]")] + rewritten[rewritten.index("[imu.identity]"):]
    assert parse_config(rewritten).imu.layout == layout


@pytest.mark.slow
def test_a_dwell_whose_samples_lack_a_health_bit_is_left_out_and_named(tmp_path):
    """sbg's status bits mean healthy when set: during the second dwell the simulated IMU reports its gyroscopes
    out of range (bit 9 clear); the run names that dwell and leaves it out, and uses the others."""
    text = config_text(noise="true", rate_hz=RATE_HZ, dwell_s=1.0).replace("[imu]\n", '[imu]\nlayout = "sbg-ecan"\n')

    def status(word):
        def action(run):
            run.world.can_imu.status = word
        return action

    plan = compile_from_config(parse_config(text))
    triggers = (Trigger(step_index(plan, "dwell", 1), status(0x03FF & ~(1 << 9))),
                Trigger(step_index(plan, "dwell", 1) + 1, status(None)))
    with api_run(text, tmp_path, *triggers) as (_, outcome):
        named = [p for p in outcome.problems if "flagged unusable by the IMU (gyros-in-range clear)" in p]
    assert len(named) == 1 and re.search(r": P\d\d: 200 of 200 samples flagged", named[0]), outcome.problems
    assert named[0].endswith("; left out")


@pytest.mark.slow
def test_an_imu_too_quiet_to_dither_its_resolution_is_flagged(tmp_path):
    """Noise off: every dwell's rounding follows its signal (a gyro bias below half a step reads 0); the budget,
    which takes the dwells' rounding as independent, says it does not cover that."""
    config = tmp_path / "bench.toml"
    config.write_text(config_text(noise="false", rate_hz=RATE_HZ).replace("[imu]\n", '[imu]\nlayout = "sbg-ecan"\n'))
    rc, _, stderr = cli(["run", "--sim", "--config", str(config), "--out", str(tmp_path / "out"), "--quiet",
                         "--no-db"])
    assert rc == 0, stderr
    flags = load_json(only_file(tmp_path / "out", "*.result.json"))["quality"]["flags"]
    assert [f for f in flags if "does not dither its output resolution (the rounding left after averaging: gyro x "
            "100%, gyro y 100%, gyro z 100%, accelerometer x 100%" in f and "do NOT cover" in f], flags
