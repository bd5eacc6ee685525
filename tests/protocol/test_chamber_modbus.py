"""The chamber's Modbus dialect with the generic map (preset "generic"; the F4P's:
tests/protocol/test_chamber_watlow_f4.py): the register map and scaling (pure), and the client over exact expected
exchanges on Modbus TCP (loopback) and RTU (a pty): requests, scaling, refusals, garbage, silence, a lost link."""

from __future__ import annotations

import pytest

from drivers.chamber import open_chamber
from drivers.chamber.base import ChamberAlarms, ChamberLimits, ChamberState
from drivers.chamber.modbus import ModbusChamber
from drivers.chamber.modbus_map import ChamberMapError, ChamberRegisterMap
from drivers.errors import (
    ChamberAlarm,
    ChamberChecksumError,
    ChamberCommandError,
    ChamberConfigError,
    ChamberConnectionError,
    ChamberLimitError,
    ChamberProtocolError,
    ChamberTimeout,
)
from drivers.modbus_frames import crc16
from tests.helpers.modbus_exchange import GONE, ModbusExchange

# The generic map's state as docs/hardware/chamber.md lays it out: 100 process value 23.4 degC (234 = 00ea), 101 unused,
# 102 alarms (door open: bit 2), 103 status (running: bit 0); 300 setpoint -20.0 degC (-200 = ff38), 301 ramp 2.0
# degC/min (20 = 0014).
BLOCK_100 = "00ea 0000 0004 0001"
BLOCK_300 = "ff38 0014"


def read(tid: int, address: int, regs: str) -> tuple[str, str]:
    n = len(regs.split())
    return (f"{tid:04x} 0000 0006 01 03 {address:04x} {n:04x}",
            f"{tid:04x} 0000 {3 + 2 * n:04x} 01 03 {2 * n:02x} {regs}")


def write(tid: int, address: int, value: str) -> tuple[str, str]:
    frame = f"{tid:04x} 0000 0006 01 06 {address:04x} {value}"
    return frame, frame


def rtu(hex_text: str) -> str:
    data = bytes.fromhex(hex_text)
    return (data + crc16(data)).hex(" ")


def client(url: str, **kw) -> ModbusChamber:
    kw.setdefault("timeout_s", 0.2)
    kw.setdefault("register_map", ChamberRegisterMap())
    return ModbusChamber(url, **kw)


# -- the map ------------------------------------------------------------------------------

def test_default_map_scales_tenths_of_a_degree_as_signed_int16():
    m = ChamberRegisterMap.default()
    assert m.encode_temperature(25.0) == 0x00FA and m.encode_temperature(-20.0) == 0xFF38
    assert m.decode_temperature(0xFF38) == pytest.approx(-20.0) and m.decode_temperature(0x7FFF) == pytest.approx(
        3276.7)
    assert m.encode_ramp(2.0) == 0x0014
    with pytest.raises(ChamberLimitError, match="int16"):
        m.encode_temperature(4000.0)
    with pytest.raises(ChamberLimitError):
        m.encode_ramp(-1.0)
    assert m.state_reads == [(100, 4), (300, 2)]


def test_state_decodes_the_documented_block_and_encodes_back():
    m = ChamberRegisterMap.default()
    blocks = [[int(w, 16) for w in BLOCK_100.split()], [int(w, 16) for w in BLOCK_300.split()]]
    state = m.decode_state(blocks, 5.0)
    assert state == ChamberState(5.0, pytest.approx(23.4), pytest.approx(-20.0), pytest.approx(2.0), True,
                                 ChamberAlarms.DOOR_OPEN, "")
    encoded = m.encode_state(state)
    assert [encoded[a] for a in (100, 102, 103, 300, 301)] == [0x00EA, 0x0004, 0x0001, 0xFF38, 0x0014]
    assert m.decode_alarms(0x8001) == (ChamberAlarms.OVER_TEMPERATURE, "alarm bit 15")
    with pytest.raises(ChamberProtocolError):
        m.decode_state([[1, 2, 3], [1, 2]])
    with pytest.raises(ChamberProtocolError, match="negative"):
        m.decode_state([[0, 0, 0, 0], [0, 0xFFFF]])


def test_map_from_configuration_and_its_errors_name_the_key():
    m = ChamberRegisterMap.from_dict({"unit": 3, "temperature_scale_c": 0.01, "registers": {"ramp_rate": -1,
                                      "process_value": 0, "alarms": 1, "status": 2, "setpoint": 3},
                                      "alarm_bits": {"door_open": 7}, "command_codes": {"run": 10}})
    assert (m.unit, m.has_ramp, m.alarm_bits[2], m.command_code("run")) == (3, False, 7, 10)
    assert m.state_reads == [(0, 4)]
    assert ChamberRegisterMap.from_dict(m.to_dict()) == m
    for bad, words in (({"registers": {"setpoint": 100}}, "overlaps"), ({"registers": {"bogus": 1}}, "bogus"),
                       ({"temperature_scale_c": 0}, "temperature_scale_c must be positive"),
                       ({"command_codes": {"run": 0}}, "0 means"), ({"alarm_bits": {"door_open": 0}}, "distinct"),
                       ({"unit": "one"}, "unit must be an integer"), ([], "must be a table")):
        with pytest.raises(ChamberMapError, match=words):
            ChamberRegisterMap.from_dict(bad, source="map.toml")


# -- the client over TCP ----------------------------------------------------------------------

def test_state_poll_is_two_reads_and_decodes_the_documented_block():
    with ModbusExchange([read(1, 100, BLOCK_100), read(2, 300, BLOCK_300)]) as ex:
        with client(ex.start_tcp()) as chamber:
            state = chamber.read_state()
    assert (state.temperature_c, state.setpoint_c, state.ramp_c_per_min) == pytest.approx((23.4, -20.0, 2.0))
    assert state.running and state.alarms == ChamberAlarms.DOOR_OPEN


def test_commands_write_ramp_then_setpoint_then_the_command_register():
    script = [write(1, 301, "0014"), write(2, 300, "ff38"), write(3, 200, "0001"), write(4, 200, "0002"),
              write(5, 200, "0003")]
    with ModbusExchange(script) as ex:
        with client(ex.start_tcp()) as chamber:
            chamber.set_setpoint(-20.0, ramp_c_per_min=2.0)
            chamber.run()
            chamber.stop()
            chamber.clear_alarms()


def test_limits_and_register_range_are_checked_before_anything_is_sent():
    # not connected: anything sent would be a ChamberConnectionError, not the limit error
    chamber = client("modbus+tcp://127.0.0.1:9", limits=ChamberLimits(-70.0, 180.0, 20.0))
    with pytest.raises(ChamberLimitError, match="outside the limits"):
        chamber.set_setpoint(200.0)
    with pytest.raises(ChamberLimitError, match="ramp rate"):
        chamber.set_setpoint(20.0, ramp_c_per_min=25.0)
    fine = client("modbus+tcp://127.0.0.1:9", register_map=ChamberRegisterMap(temperature_scale_c=0.01),
                  limits=ChamberLimits(-270.0, 999.0, 20.0))
    with pytest.raises(ChamberLimitError, match="int16"):
        fine.set_setpoint(500.0)


def test_a_map_without_ramp_refuses_a_ramp_before_sending():
    no_ramp = ChamberRegisterMap(ramp_rate=-1)
    blocks = [read(1, 100, BLOCK_100), read(2, 300, "ff38")]
    with ModbusExchange(blocks) as ex:
        with client(ex.start_tcp(), register_map=no_ramp) as chamber:
            with pytest.raises(ChamberConfigError, match="no ramp"):
                chamber.set_setpoint(25.0, ramp_c_per_min=1.0)
            assert chamber.read_state().ramp_c_per_min is None


def test_an_exception_reply_is_a_command_error_with_its_code():
    with ModbusExchange([("0001 0000 0006 01 06 00c8 0001", "0001 0000 0003 01 86 04")]) as ex:
        with client(ex.start_tcp()) as chamber, pytest.raises(ChamberCommandError, match="server device failure") \
                as info:
            chamber.run()
    assert info.value.code == 4


def test_silence_is_retried_then_a_timeout():
    script = [("0001 0000 0006 01 03 0064 0004", None), ("0002 0000 0006 01 03 0064 0004", None)]
    with ModbusExchange(script) as ex:
        with client(ex.start_tcp(), retries=1, timeout_s=0.1) as chamber, pytest.raises(ChamberTimeout,
                                                                                        match="2 attempts"):
            chamber.read_state()


def test_an_alarm_word_raises_chamber_alarm():
    with ModbusExchange([read(1, 100, "03e8 0000 0001 0000"), read(2, 300, "0352 0000")]) as ex:
        with client(ex.start_tcp()) as chamber, pytest.raises(ChamberAlarm, match="over-temperature") as info:
            chamber.check_state()
    assert info.value.state.temperature_c == pytest.approx(100.0) and not info.value.state.running


def test_a_controller_that_goes_away_is_a_connection_error():
    with ModbusExchange([GONE]) as ex:
        chamber = client(ex.start_tcp(), retries=0).connect()
        try:
            with pytest.raises(ChamberConnectionError):
                chamber.read_state()
        finally:
            chamber.close()


# -- the client over RTU on a pty --------------------------------------------------------------

def test_rtu_exchange_and_a_bad_crc_is_a_checksum_error():
    reply = rtu("01 03 08 00ea 0000 0004 0001")
    corrupted = reply[:-2] + ("00" if reply[-2:] != "00" else "11")
    request = rtu("01 03 0064 0004")
    script = [(rtu("01 06 012c 00fa"), rtu("01 06 012c 00fa")), (request, reply), (rtu("01 03 012c 0002"),
                                                                                   rtu("01 03 04 00fa 0000")),
              (request, corrupted)]
    with ModbusExchange(script) as ex:
        with client(ex.start_pty(), retries=0) as chamber:
            chamber.set_setpoint(25.0)
            assert chamber.read_state().setpoint_c == pytest.approx(25.0)
            with pytest.raises(ChamberChecksumError, match="CRC"):
                chamber.read_state()


def test_open_chamber_takes_modbus_urls():
    assert isinstance(open_chamber("modbus+tcp://127.0.0.1:1502"), ModbusChamber)
    with pytest.raises(ChamberConfigError, match="needs a modbus"):
        open_chamber("tcp://127.0.0.1:1", "modbus")
    with pytest.raises(ChamberConfigError, match="unit"):
        open_chamber("modbus+tcp://127.0.0.1:1502?unit=999")
