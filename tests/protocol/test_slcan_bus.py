"""The bulk SLCAN reader (`drivers.imu.slcan_bus.BulkSlcanBus`) against a raw pty and against the rig's adapter.

The pty's other end is this test (it writes what an adapter sends and reads what the bus
sends), or the simulated CANable of `bench sim rig` (`SlcanPtyServer`). Compatibility with
python-can's own `slcan` interface is checked on the wire: both send the same bytes for the
same frames and open and close the adapter with the same commands. Loopback ptys only; every
wait is bounded.
"""

from __future__ import annotations

import os
import select
import time

import can
import pytest

from bench.config.load import parse_config
from bench.sim.rig import SimRig
from bench.sim.slcan_server import SlcanPtyServer
from drivers.errors import ImuConfigError
from drivers.imu.receiver import ImuReceiver, open_bus
from drivers.imu.slcan_bus import BulkSlcanBus
from tests.helpers.run import config_text


@pytest.fixture
def pty():
    """(master fd, slave path): the test is the adapter."""
    master, slave = os.openpty()
    path = os.ttyname(slave)
    yield master, path
    os.close(master)
    os.close(slave)


def _read_master(master: int, timeout_s: float = 2.0, until: bytes | None = None) -> bytes:
    """What the bus wrote, read until `until` appears or nothing comes for 0.2 s (bounded by `timeout_s`)."""
    got = b""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.2)
        if not ready:
            if until is None:
                break
            continue
        got += os.read(master, 4096)
        if until is not None and until in got:
            break
    return got


def _recv_all(bus: can.BusABC, n: int, timeout_s: float = 5.0) -> list[can.Message]:
    out: list[can.Message] = []
    deadline = time.monotonic() + timeout_s
    while len(out) < n and time.monotonic() < deadline:
        msg = bus.recv(0.1)
        if msg is not None:
            out.append(msg)
    return out


def test_opens_and_closes_the_adapter_with_python_cans_commands(pty):
    master, path = pty
    bus = BulkSlcanBus(path, bitrate=1_000_000, sleep_after_open=0)
    assert _read_master(master) == b"C\rS8\rO\r"
    bus.shutdown()
    assert _read_master(master) == b"C\r"
    listen = BulkSlcanBus(path + "@115200", sleep_after_open=0, listen_only=True)   # python-can's channel syntax
    assert _read_master(master) == b"C\rL\r"
    listen.shutdown()
    with pytest.raises(ValueError, match="invalid SLCAN bit rate"):
        BulkSlcanBus(path, bitrate=123_456, sleep_after_open=0)
    with pytest.raises(can.CanInitializationError, match="cannot open the SLCAN port"):
        BulkSlcanBus("/nonexistent/tty", sleep_after_open=0)


def test_sends_the_bytes_python_cans_slcan_interface_sends(pty):
    master, path = pty
    messages = [can.Message(arbitration_id=0x123, data=b"\x11\x22\x33", is_extended_id=False),
                can.Message(arbitration_id=0x1ABCDEF, data=bytes(range(8)), is_extended_id=True),
                can.Message(arbitration_id=0x7FF, data=b"", is_extended_id=False),
                can.Message(arbitration_id=0x10, is_remote_frame=True, dlc=4, is_extended_id=False),
                can.Message(arbitration_id=0x10, is_remote_frame=True, dlc=2, is_extended_id=True),
                can.Message(arbitration_id=0x110, data=bytes(range(24)), is_fd=True, is_extended_id=False),
                can.Message(arbitration_id=0x110, data=bytes(12), is_fd=True, bitrate_switch=True,
                            is_extended_id=True)]
    wire = {}
    for name, make in (("bench", lambda: BulkSlcanBus(path, sleep_after_open=0)),
                       ("python-can", lambda: can.Bus(interface="slcan", channel=path, sleep_after_open=0))):
        bus = make()
        _read_master(master)                      # the opening commands
        for msg in messages:
            bus.send(msg)
        wire[name] = _read_master(master, until=b"B000001109" + b"00" * 12 + b"\r")
        bus.shutdown()
        _read_master(master)
    assert wire["bench"] == wire["python-can"]
    assert wire["bench"].startswith(b"t1233112233\rT01ABCDEF80001020304050607\rt7FF0\rr0104\rR000000102\r")


def test_parses_every_frame_of_a_read_and_counts_garbage(pty):
    master, path = pty
    bus = BulkSlcanBus(path, sleep_after_open=0)
    _read_master(master)
    os.write(master, b"t1233112233\rT01ABCDEF80001020304050607\rt7FF0\rr1004\rR000000102\r"
                     b"t12021122EA60\r"            # Z1: a 4-digit adapter timestamp after the data (ignored)
                     b"d110C" + bytes(range(24)).hex().upper().encode() + b"\r"
                     b"B00000110" + b"9" + b"00" * 12 + b"\r"
                     b"\r\az\rhello\rt12" + b"X1AA\r"   # OK, error, transmit ack, junk, a bad dlc
                     b"t1232AABB\r\n"              # CR LF line ends
                     b"t12")
    os.write(master, b"31CC\r")                      # a frame split across two writes
    got = _recv_all(bus, 10)
    assert [(m.arbitration_id, m.is_extended_id, m.is_remote_frame, m.is_fd, bytes(m.data), m.dlc) for m in got] == [
        (0x123, False, False, False, b"\x11\x22\x33", 3),
        (0x1ABCDEF, True, False, False, bytes(range(8)), 8),
        (0x7FF, False, False, False, b"", 0),
        (0x100, False, True, False, b"", 4),
        (0x10, True, True, False, b"", 2),
        (0x120, False, False, False, b"\x11\x22", 2),
        (0x110, False, False, True, bytes(range(24)), 24),
        (0x110, True, False, True, bytes(12), 12),
        (0x123, False, False, False, b"\xaa\xbb", 2),
        (0x123, False, False, False, b"\xcc", 1)]
    assert got[7].bitrate_switch and not got[6].bitrate_switch
    assert bus.malformed_lines == 2 and bus.error_replies == 1
    assert all(abs(m.timestamp - time.time()) < 60 for m in got)    # the host's receive time, as python-can's
    os.write(master, b"x" * 500)                     # no line end in sight: bounded, counted, dropped
    assert bus.recv(0.3) is None and bus.malformed_lines == 3
    bus.shutdown()


def test_drain_hands_over_every_queued_frame_in_one_call(pty):
    master, path = pty
    bus = BulkSlcanBus(path, sleep_after_open=0)
    _read_master(master)
    os.write(master, b"".join(b"t1001%02X\r" % k for k in range(200)))
    first = bus.recv(2.0)
    rest = bus.drain_messages(150)
    rest += bus.drain_messages()
    assert [first.data[0]] + [m.data[0] for m in rest] == list(range(200))
    bus.set_filters([{"can_id": 0x200, "can_mask": 0x7FF}])
    os.write(master, b"t1001AA\rt2001BB\r")
    time.sleep(0.05)
    assert [bytes(m.data) for m in bus.drain_messages()] == [b"\xbb"]
    bus.shutdown()


def test_open_bus_reads_slcan_in_bulk_unless_told_otherwise():
    with SlcanPtyServer() as server:
        kwargs = {"interface": "slcan", "channel": server.path, "bitrate": 1_000_000, "sleep_after_open": 0}
        bus = open_bus(kwargs)
        assert isinstance(bus, BulkSlcanBus)
        assert bus.get_version(2.0) == (10, 13) and bus.get_serial_number(2.0) == "A123"
        bus.shutdown()
        bus = open_bus({**kwargs, "slcan_client": "python-can"})
        assert type(bus).__name__ == "slcanBus"
        bus.shutdown()
        with pytest.raises(ImuConfigError, match="slcan_client must be one of bench, python-can"):
            open_bus({**kwargs, "slcan_client": "fast"})


@pytest.mark.slow        # two seconds of the rig's IMU at its rate, each
@pytest.mark.parametrize("layout, rate_hz, client", [("packed", 2000.0, "bench"), ("classic", 400.0, "bench"),
                                                     ("packed", 400.0, "python-can")])
def test_receives_the_rigs_imu_at_2_khz_without_loss_across_reconnects(layout, rate_hz, client):
    """The bulk reader at 2 kHz; python-can's own slcan class reads the same rig's packed frames (slower)."""
    config = parse_config(config_text(rate_hz=rate_hz, noise="true").replace(
        "rate_hz =", f'layout = "{layout}"\nrate_hz ='))
    with SimRig(config) as rig:
        peer = rig.serve_slcan()
        rig.start()
        kwargs = {"interface": "slcan", "channel": peer.channel, "bitrate": peer.bitrate, "sleep_after_open": 0,
                  "slcan_client": client}
        for _ in range(2):                           # connect, receive a second of samples, go; then again
            with ImuReceiver(kwargs, config.imu.layout, rate_hz) as receiver:
                assert isinstance(receiver.bus, BulkSlcanBus) == (client == "bench")
                counters = []
                deadline = time.monotonic() + 30.0
                while sum(map(len, counters)) < rate_hz and time.monotonic() < deadline:
                    counters.append(receiver.poll(timeout_s=0.02).counter)
                got = [int(c) for block in counters for c in block]
                assert len(got) >= rate_hz and got == list(range(got[0], got[0] + len(got)))
                stats = receiver.stats
                assert stats.lost_samples == 0 and stats.frame_faults == 0, stats
                assert getattr(receiver.bus, "malformed_lines", 0) == 0
        assert rig.server(0).frames_dropped == 0


def _adapter_left_open(master: int, stale: bytes, fresh: bytes) -> None:
    """The adapter side, left open by another client: frames it sent before the bus's `C` took effect (`stale`)
    reach the port after the bus opened it, then the answer to `C`; it answers each command with CR and sends
    `fresh` once the bus has opened the channel again (`O`)."""
    seen = b""
    deadline = time.monotonic() + 5.0
    while b"O\r" not in seen and time.monotonic() < deadline:
        ready, _, _ = select.select([master], [], [], 0.1)
        if ready:
            got = os.read(master, 4096)
            if b"C\r" in got and b"C\r" not in seen:
                os.write(master, stale)
            seen += got
            os.write(master, b"\r" * got.count(b"\r"))
    os.write(master, fresh)


def test_frames_sent_before_the_bus_opened_the_channel_are_dropped(pty):
    """Issue 27: a healthy IMU on SLCAN was refused ("sends about 7.3e+04 samples/s") when another client had left
    the adapter open: the reader kept the frames queued before its own open, all stamped with one time."""
    import threading
    import tty

    master, path = pty
    tty.setraw(os.open(path, os.O_RDWR | os.O_NOCTTY))     # raw: no line discipline between the two ends
    stale = b"".join(b"t1001%02X\r" % (k % 256) for k in range(150))
    fresh = b"".join(b"t2001%02X\r" % k for k in range(5))
    adapter = threading.Thread(target=_adapter_left_open, args=(master, stale, fresh))
    adapter.start()
    bus = BulkSlcanBus(path, sleep_after_open=0)
    adapter.join(5.0)
    got = _recv_all(bus, 5)
    assert [m.arbitration_id for m in got] == [0x200] * 5
    assert bus.stale_frames == 150 and bus.recv(0.1) is None
    bus.shutdown()


def test_each_frame_of_one_read_gets_its_own_receive_time(pty):
    """The frames of one read are spread between the previous read and this one by where each line ends."""
    master, path = pty
    bus = BulkSlcanBus(path, sleep_after_open=0, close_ack_timeout_s=0)
    _read_master(master)
    data = b"".join(b"t1001%02X\r" % k for k in range(4))     # 4 lines of 8 bytes each
    bus._parse(data, 100.0, 101.0)
    assert [m.timestamp for m in bus.drain_messages()] == [100.25, 100.5, 100.75, 101.0]
    bus._parse(data[:5], 101.0, 102.0)                         # a line begun in one read ends in the next
    bus._parse(data[5:16], 102.0, 103.0)
    assert [m.timestamp for m in bus.drain_messages()] == [102.0 + 3 / 11, 103.0]   # line ends: 3 and 11 of 11
    os.write(master, b"".join(b"t1001%02X\r" % k for k in range(200)))
    time.sleep(0.05)
    stamps = [m.timestamp for m in bus.drain_messages()]
    assert len(stamps) == 200 and stamps == sorted(stamps) and len(set(stamps)) > 1
    bus.shutdown()
