"""The Watlow F4P's Modbus map (preset "watlow-f4", the modbus dialect's default): the codec (pure) and the client
over exact expected exchanges at the F4P's own register numbers.

Every number below is the F4P manual's relative register number (chapter 9, "Modbus Registers", the lists sorted
alphabetically and by number; add 40001 for its absolute number), which is the 0-based address on the wire:
  100 Input 1 Value, 101 Input 1 Error, 102 Alarm 1 status, 106 Alarm 2 status (0 off, 1 high, 2 low),
  200 Auto/Manual Mode (1 auto, 2 manual), 210 Input 1 Open Loop, 300 Set Point 1,
  311 / 312 / 331 Clear Error Input 1 / Clear Alarm 1 / Clear Alarm 2 (write any value),
  452 / 453 Maximum Transfer Heat / Cool (tenths of a percent: the power manual mode may hold),
  602 / 603 Set Point Low / High Limit (input 1), 606 Decimal (input 1: 0 to 3 places), 901 degF or degC (0 F, 1 C),
  1100 Ramp to Set Point Mode (0 off, 1 startup, 2 startup or change), 1101 its rate (1-999 counts at input 1's
  decimals), 1102 its time base (0 per minute, 1 per hour). Ranges and the decimal rule: chapter 6 (Operations and
  Setup page parameter tables).
"""

from __future__ import annotations

import pytest

from drivers.chamber import open_chamber
from drivers.chamber.base import ChamberAlarms, ChamberLimits
from drivers.chamber.modbus import ModbusChamber
from drivers.chamber.watlow_f4 import REGISTERS, WatlowF4Map, is_f4p_register
from drivers.errors import ChamberAlarm, ChamberCommandError, ChamberLimitError, ChamberProtocolError
from tests.helpers.modbus_exchange import ModbusExchange
from tests.protocol.test_chamber_modbus import read, rtu, write

WIDE = ChamberLimits(-100.0, 200.0, 30.0)

# Connecting reads the settings that scale every value: 452-453 (maximum transfer heat and cool 0 %: manual mode is
# outputs off), 602-606 (set point low limit -72.0, high limit 120.0, filter 1.0, calibration offset 0, decimal 1:
# one place) and 901 (1: degC).
NO_TRANSFER = read(1, 452, "0000 0000")
SETTINGS_1_DECIMAL_C = [NO_TRANSFER, read(2, 602, "fd30 04b0 000a 0000 0001"), read(3, 901, "0001")]
# One state poll, five reads: 100-106 (23.4 degC, no input error, alarm 1 off, 103-105 power and unused, alarm 2
# low), 200 (auto: running), 210 (no open loop), 300 (set point 1 -20.0 degC = -200 = ff38), 1100-1102 (ramp on
# start or change, 20 counts = 2.0, per minute).
STATE = ["00ea 0000 0000 01f4 0000 0000 0002", "0001", "0000", "ff38", "0002 0014 0000"]
STATE_ADDRESSES = (100, 200, 210, 300, 1100)


def state_reads(first_tid: int, blocks: list[str] = STATE) -> list[tuple[str, str]]:
    return [read(first_tid + i, address, regs) for i, (address, regs) in enumerate(zip(STATE_ADDRESSES, blocks))]


def client(url: str, **kw) -> ModbusChamber:
    kw.setdefault("timeout_s", 0.5)
    kw.setdefault("limits", WIDE)
    return ModbusChamber(url, **kw)


# -- the codec ----------------------------------------------------------------------------------

def test_the_preset_holds_the_manuals_register_numbers():
    assert REGISTERS == {"process_value": 100, "input_error": 101, "alarm_1": 102, "alarm_2": 106, "mode": 200,
                         "open_loop": 210, "setpoint": 300, "clear_input_error": 311, "clear_alarm_1": 312,
                         "clear_alarm_2": 331, "max_transfer_heat": 452, "max_transfer_cool": 453,
                         "setpoint_low_limit": 602, "setpoint_high_limit": 603, "decimal": 606,
                         "units": 901, "ramp_mode": 1100, "ramp_rate": 1101, "ramp_scale": 1102}
    assert all(is_f4p_register(n) for n in REGISTERS.values())
    # the generic map's 103 and 200 are other things on the F4P (power output 1A, auto/manual): the lists agree
    assert is_f4p_register(103) and not is_f4p_register(104) and not is_f4p_register(1103)


@pytest.mark.parametrize("decimals, fahrenheit, word, value_c", [
    (0, False, 0x0017, 23.0), (1, False, 0x00EA, 23.4), (2, False, 0x0929, 23.45), (3, False, 0x5B9A, 23.45),
    (1, False, 0xFF38, -20.0), (0, True, 0x004A, (74 - 32) * 5 / 9), (1, True, 0xFFD8, (-4.0 - 32) * 5 / 9),
])
def test_the_decimal_register_scales_every_value(decimals, fahrenheit, word, value_c):
    m = WatlowF4Map(decimals=decimals, fahrenheit=fahrenheit)
    assert m.decode_temperature(word) == pytest.approx(value_c)
    assert m.encode_temperature(value_c) == word


def test_the_ramp_is_the_ramp_to_set_point_and_its_time_base():
    m = WatlowF4Map(decimals=1)
    assert m.ramp_writes(2.0) == [(1102, 0, "ramp 2 degC/min"), (1101, 20, "ramp 2 degC/min"),
                                  (1100, 2, "ramp 2 degC/min")]
    assert m.ramp_words(0.05) == (30, 1)              # 3.0 degC per hour: per minute it would round to 0 or 1 count
    assert m.ramp_writes(0) == [(1100, 0, "ramp to set point off")]
    assert m.decode_ramp(0, 20, 0) == 0.0 and m.decode_ramp(2, 20, 0) == pytest.approx(2.0)
    assert m.decode_ramp(1, 30, 1) == pytest.approx(0.05)
    assert WatlowF4Map(decimals=0, fahrenheit=True).ramp_words(2.0) == (216, 1)   # 3.6 degF/min: exact per hour
    with pytest.raises(ChamberLimitError, match="1-999 counts"):
        m.ramp_words(150.0)
    with pytest.raises(ChamberProtocolError, match="mode 5"):
        m.decode_ramp(5, 20, 0)


def test_alarm_status_enumeration_and_the_error_registers():
    m = WatlowF4Map(decimals=1)
    words = {"alarm_1": 1, "alarm_2": 0, "input_error": 0, "open_loop": 0}
    assert m.decode_alarms(words) == (ChamberAlarms.OVER_TEMPERATURE, "")
    assert m.decode_alarms({**words, "alarm_1": 2}) == (ChamberAlarms.UNDER_TEMPERATURE, "")
    assert m.decode_alarms({**words, "alarm_1": 0, "alarm_2": 1}) == (ChamberAlarms.OVER_TEMPERATURE, "")
    assert m.decode_alarms({**words, "alarm_1": 0, "input_error": 3}) == (ChamberAlarms.SENSOR_FAULT, "")
    assert m.decode_alarms({**words, "alarm_1": 0, "open_loop": 1}) == (ChamberAlarms.EQUIPMENT_FAULT, "")
    assert m.decode_alarms({**words, "alarm_1": 5, "input_error": 9}) == (ChamberAlarms.SENSOR_FAULT,
                                                                          "alarm 1 status 5, input 1 error 9")


def test_values_need_the_decimal_setting_read_first():
    with pytest.raises(ChamberProtocolError, match="connect first"):
        WatlowF4Map().encode_temperature(20.0)


# -- the client over Modbus TCP --------------------------------------------------------------------

def test_connect_reads_the_settings_and_the_state_poll_decodes_the_f4p_registers():
    with ModbusExchange(SETTINGS_1_DECIMAL_C + state_reads(4)) as ex:
        with client(ex.start_tcp()) as chamber:
            assert chamber.map.decimals == 1 and not chamber.map.fahrenheit
            assert chamber.map.setpoint_limits_c == pytest.approx((-72.0, 120.0))
            state = chamber.read_state()
    assert (state.temperature_c, state.setpoint_c, state.ramp_c_per_min) == pytest.approx((23.4, -20.0, 2.0))
    assert state.running and state.alarms == ChamberAlarms.UNDER_TEMPERATURE


def test_commands_write_the_f4p_registers_in_order():
    script = SETTINGS_1_DECIMAL_C + [
        write(4, 1102, "0000"), write(5, 1101, "0014"), write(6, 1100, "0002"),   # 2.0 degC/min, then on
        write(7, 300, "ff38"),                                                   # set point 1 -20.0 degC
        write(8, 200, "0001"), write(9, 200, "0002"),                            # auto (run), manual (stop)
        write(10, 311, "0001"), write(11, 312, "0001"), write(12, 331, "0001"),   # clear input error, alarms 1, 2
        write(13, 1100, "0000"), write(14, 300, "00fa"),                         # ramp off: step to 25.0 degC
    ]
    with ModbusExchange(script) as ex:
        with client(ex.start_tcp()) as chamber:
            chamber.set_setpoint(-20.0, ramp_c_per_min=2.0)
            chamber.run()
            chamber.stop()
            chamber.clear_alarms()
            chamber.set_setpoint(25.0, ramp_c_per_min=0)


def test_two_decimals_and_fahrenheit_scale_reads_and_writes():
    # limits -1000 .. 12000 counts, 0 decimals, degF
    settings = [NO_TRANSFER, read(2, 602, "fc18 2ee0 000a 0000 0000"), read(3, 901, "0000")]
    state = ["004a 0000 0000 0000 0000 0000 0000", "0002", "0000", "fffc", "0000 0001 0000"]
    with ModbusExchange(settings + state_reads(4, state) + [write(9, 300, "0032")]) as ex:
        with client(ex.start_tcp()) as chamber:
            s = chamber.read_state()
            assert s.temperature_c == pytest.approx((74 - 32) * 5 / 9) and s.setpoint_c == pytest.approx(-20.0)
            assert not s.running and s.ramp_c_per_min == 0.0
            chamber.set_setpoint(10.0)                       # 50 degF = 0032
    with ModbusExchange([NO_TRANSFER, read(2, 602, "f830 2ee0 000a 0000 0002"), read(3, 901, "0001"),
                         read(4, 100, "0929 0000 0000 0000 0000 0000 0000")]) as ex:
        with client(ex.start_tcp()) as chamber:
            assert chamber.map.decimals == 2
            assert chamber.map.decode_temperature(chamber._read(100, 7, "input 1")[0]) == pytest.approx(23.45)


def test_a_setpoint_beyond_the_f4p_limits_is_refused_before_sending():
    with ModbusExchange(SETTINGS_1_DECIMAL_C) as ex:        # nothing after the settings: a send would fail it
        with client(ex.start_tcp()) as chamber:
            with pytest.raises(ChamberLimitError, match=r"set point limits \[-72, 120\] degC \(registers 602, 603\)"):
                chamber.set_setpoint(150.0)
            with pytest.raises(ChamberLimitError, match="1-999 counts"):
                chamber.set_setpoint(20.0, ramp_c_per_min=0.001)


@pytest.mark.parametrize("settings, message", [
    ("fd30 04b0 000a 0000 0007", "decimal register holds 7"),
])
def test_settings_the_manual_does_not_list_are_protocol_errors(settings, message):
    with ModbusExchange([NO_TRANSFER, read(2, 602, settings), read(3, 901, "0001")]) as ex:
        chamber = client(ex.start_tcp())
        with pytest.raises(ChamberProtocolError, match=message):
            chamber.connect()


def test_units_register_other_than_0_or_1_is_a_protocol_error():
    with ModbusExchange([NO_TRANSFER, read(2, 602, "fd30 04b0 000a 0000 0001"), read(3, 901, "0002")]) as ex:
        with pytest.raises(ChamberProtocolError, match="degF/degC register 901 holds 2"):
            client(ex.start_tcp()).connect()


def test_an_alarm_and_an_unknown_mode_in_the_state():
    alarmed = ["00ea 0003 0001 0000 0000 0000 0000", "0002", "0001", "ff38", "0000 0014 0000"]
    with ModbusExchange(SETTINGS_1_DECIMAL_C + state_reads(4, alarmed) + state_reads(9, STATE[:1] + ["0000"]
                                                                                      + STATE[2:])) as ex:
        with client(ex.start_tcp()) as chamber:
            with pytest.raises(ChamberAlarm, match="over-temperature, sensor fault, equipment fault"):
                chamber.check_state()
            with pytest.raises(ChamberProtocolError, match="auto/manual register 200 holds 0"):
                chamber.read_state()


def test_a_stop_that_may_hold_power_says_so():
    # 452 = 1000 (100.0 % heat), 453 = -500 = fe0c (-50.0 % cool): manual mode may keep the outputs on
    settings = [read(1, 452, "03e8 fe0c")] + SETTINGS_1_DECIMAL_C[1:]
    with ModbusExchange(settings + [write(4, 200, "0002")]) as ex:
        with client(ex.start_tcp()) as chamber:
            assert chamber.make_safe() == ("stopped (manual mode may hold up to 100 % heat and -50 % cool power: the "
                                           "F4P's Maximum Transfer Heat/Cool, registers 452/453)")


def test_an_f4p_exception_reply_is_a_command_error():
    # the manual's exception codes: 01 illegal command, 02 illegal data address, 03 illegal data value
    with ModbusExchange(SETTINGS_1_DECIMAL_C + [("0004 0000 0006 01 06 00c8 0001", "0004 0000 0003 01 86 03")]) as ex:
        with client(ex.start_tcp()) as chamber, pytest.raises(ChamberCommandError) as info:
            chamber.run()
    assert info.value.code == 3


def test_rtu_frames_carry_the_same_register_numbers():
    script = [(rtu("01 03 01c4 0002"), rtu("01 03 04 0000 0000")),
              (rtu("01 03 025a 0005"), rtu("01 03 0a fd30 04b0 000a 0000 0001")),
              (rtu("01 03 0385 0001"), rtu("01 03 02 0001")),
              (rtu("01 06 012c 00fa"), rtu("01 06 012c 00fa"))]
    with ModbusExchange(script) as ex:
        with client(ex.start_pty()) as chamber:
            chamber.set_setpoint(25.0)


def test_open_chamber_defaults_to_the_f4p_map():
    chamber = open_chamber("modbus+tcp://127.0.0.1:1502")
    assert isinstance(chamber, ModbusChamber) and chamber.map == WatlowF4Map()


@pytest.mark.parametrize("decimals, fahrenheit", [(0, False), (2, False), (1, True)])
def test_the_simulated_f4p_with_other_settings_is_read_the_same(decimals, fahrenheit):
    """The simulator serves the decimal and degF/degC settings it is given; the client reads them at connect and
    every value comes back in degC within the wire's resolution."""
    from bench.sim.chamber import ChamberPhysics, SimChamber
    from bench.sim.chamber_server import ChamberModbusServer
    from drivers.clock import ManualClock

    clock = ManualClock()
    sim = SimChamber(ChamberPhysics(), clock)
    server = ChamberModbusServer(sim, WatlowF4Map(decimals=decimals, fahrenheit=fahrenheit))
    try:
        host, port = server.start_tcp()
        with client(f"modbus+tcp://{host}:{port}", timeout_s=3.0) as chamber:
            assert (chamber.map.decimals, chamber.map.fahrenheit) == (decimals, fahrenheit)
            chamber.set_setpoint(-20.0, ramp_c_per_min=2.0)
            chamber.run()
            clock.advance(600.0)
            state, truth = chamber.check_state(), sim.state()
    finally:
        server.close()
    resolution_c = 10.0 ** -decimals * (5.0 / 9.0 if fahrenheit else 1.0)
    assert truth.setpoint_c == pytest.approx(-20.0, abs=resolution_c / 2 + 1e-9)
    assert truth.ramp_c_per_min == pytest.approx(2.0, rel=0.05) and state.running
    assert state.temperature_c == pytest.approx(truth.temperature_c, abs=resolution_c / 2 + 1e-9)
    assert state.ramp_c_per_min == pytest.approx(truth.ramp_c_per_min)
