"""The simulated chamber served in both dialects (docs/hardware/chamber.md): ASCII lines and Modbus TCP/RTU.

`ChamberAsciiHandler(chamber)` is a `LineServer` handler: one request line in, one reply
line out, parsed with the client's own codec. `ChamberModbusServer(chamber, map)` serves
a register map (reads computed from the live state, writes executed as commands): the
Watlow F4P's by default (`bench.sim.chamber_f4`), or the generic map (`GenericFace`).
Refusals: `SimChamberError` ERR_RANGE -> `NA:OUT OF RANGE` / exception 03 illegal data
value; ERR_ALARM -> `NA:ALARM ACTIVE` / exception 04 server device failure (03 on the F4P's map,
whose manual lists 01-03 only); an unknown command -> `NA:COMMAND ERR` / 03; a write to a
read-only register -> 02.

Wire faults (`chamber.faults`, one per reply) as the table simulator's: timeout (the
command executes, no reply), garbage (junk instead of the reply), checksum (ASCII: one
character's top bit flipped, as a parity error would; Modbus: a bad CRC or MBAP length),
exception (not executed; `NA:INJECTED <code>` or Modbus exception `exception_code`), late
(ASCII: the reply comes just before the next one).
"""

from __future__ import annotations

from typing import Callable

from pymodbus.constants import ExcCodes

from bench.sim.chamber import ERR_ALARM, ERR_RANGE, SimChamber, SimChamberError
from bench.sim.chamber_f4 import WatlowF4Face
from bench.sim.modbus_serving import ModbusServing, Refused
from bench.sim.serve import IDLE_TIMEOUT_S, LineServer, flip_parity, held_first, reply_with_fault, serve_lines
from drivers.chamber import ascii_codec as codec
from drivers.chamber.modbus_map import READ_ONLY, ChamberRegisterMap
from drivers.chamber.presets import ChamberMap, default_map
from drivers.chamber.watlow_f4 import WatlowF4Map
from drivers.errors import DeviceError

GARBAGE = b"\x00\xfe#?%garbage\x1b"
NA_FOR_ERROR = {ERR_RANGE: codec.NA_RANGE, ERR_ALARM: codec.NA_ALARM}
EXCEPTION_FOR_ERROR = {ERR_RANGE: ExcCodes.ILLEGAL_VALUE, ERR_ALARM: ExcCodes.DEVICE_FAILURE}


class ChamberAsciiHandler:
    """`(line: bytes) -> bytes | None`: the ASCII face of a SimChamber."""

    def __init__(self, chamber: SimChamber):
        self.chamber = chamber

    def __call__(self, line: bytes) -> bytes | None:
        return held_first(self.chamber.faults, lambda: reply_with_fault(
            self.chamber.faults, lambda: self.reply(line),
            exception_reply=lambda code: codec.format_na(f"INJECTED {code}"),
            garbage=GARBAGE + codec.TERMINATOR, corrupt=lambda reply: flip_parity(reply, codec.TERMINATOR)))

    def reply(self, line: bytes) -> bytes:
        """The reply to one request line, with its terminator (no faults)."""
        try:
            request = codec.parse_request(line)
        except codec.RequestError as exc:
            return codec.format_na(exc.reason)
        c = self.chamber
        try:
            if request.name == "MON?":
                return codec.format_monitor(c.state())
            if request.name == "TEMP?":
                state = c.state()
                return (f"{codec.format_temperature(state.temperature_c)},"
                        f"{codec.format_temperature(state.setpoint_c)}").encode("ascii") + codec.TERMINATOR
            if request.name == "RAMP?":
                return codec.format_temperature(c.state().ramp_c_per_min or 0.0).encode("ascii") + codec.TERMINATOR
            if request.name == "MODE?":
                return (b"RUN" if c.state().running else b"STOP") + codec.TERMINATOR
            if request.name == "ALARM?":
                return codec.format_alarm_fields(c.state().alarms).encode("ascii") + codec.TERMINATOR
            if request.name == "TEMP,S":
                assert isinstance(request.value, float)
                c.set_setpoint(request.value)
            elif request.name == "RAMP":
                assert isinstance(request.value, float)
                c.set_ramp(request.value)
            elif request.name == "MODE":
                (c.run if request.value == "RUN" else c.stop)()
            elif request.name == "ALARM,CLEAR":
                c.clear_alarms()
        except SimChamberError as exc:
            return codec.format_na(NA_FOR_ERROR.get(exc.code, codec.NA_COMMAND))
        return codec.format_ok(line)


class GenericFace:
    """The generic map's registers over a SimChamber: `image()` for reads, `write(address, value)` for writes."""

    def __init__(self, chamber: SimChamber, register_map: ChamberRegisterMap):
        self.chamber, self.map = chamber, register_map
        self._names = register_map.register_names()

    def read_only(self, address: int) -> bool:
        return self._names.get(address) in (None, *READ_ONLY)      # unused and read-only registers refuse writes

    def image(self) -> dict[int, int]:
        return self.map.encode_state(self.chamber.state())

    def write(self, address: int, value: int) -> None:
        name, m, c = self._names.get(address), self.map, self.chamber
        actions: dict[str, Callable[[], None]] = {
            "setpoint": lambda: c.set_setpoint(m.decode_temperature(value)),
            "ramp_rate": lambda: c.set_ramp(m.decode_ramp(value)),
            "command": lambda: {"run": c.run, "stop": c.stop, "clear_alarms": c.clear_alarms}[
                m.decode_command(value)](),
        }
        if name not in actions:
            raise Refused(ExcCodes.ILLEGAL_ADDRESS, f"register {address} ({name or 'unused'}) is not writable")
        actions[name]()


class ChamberModbusServer(ModbusServing):
    """The simulated chamber as a Modbus server (TCP listeners and RTU ptys, `ModbusServing`) serving a register
    map (default: the Watlow F4P's, `bench.sim.chamber_f4`)."""

    device_errors = (DeviceError,)
    device_error_code = ExcCodes.ILLEGAL_VALUE

    def __init__(self, chamber: SimChamber, register_map: ChamberMap | None = None, **kwargs):
        super().__init__(**kwargs)
        self.chamber = chamber
        self.wire_faults = chamber.faults
        register_map = register_map if register_map is not None else default_map()
        self.face: WatlowF4Face | GenericFace = (WatlowF4Face(chamber, register_map)
                                                 if isinstance(register_map, WatlowF4Map)
                                                 else GenericFace(chamber, register_map))
        #: the map as served (the F4P's with the simulated controller's settings)
        self.map: ChamberMap = self.face.map
        # the F4P's manual lists exception codes 01-03 only: its run-while-alarmed refusal is 03
        self._exceptions = EXCEPTION_FOR_ERROR if isinstance(self.face, GenericFace) else {}
        self._device = self._register_device(self.map.unit, self.map.register_names(), self.face.read_only)

    def _read_image(self) -> dict[int, int]:
        return self.face.image()

    def _write(self, address: int, values: list[int]) -> None:
        for i, value in enumerate(values):
            try:
                self.face.write(address + i, value)
            except SimChamberError as exc:
                raise Refused(self._exceptions.get(exc.code, ExcCodes.ILLEGAL_VALUE), str(exc)) from exc


def serve_chamber_ascii(chamber: SimChamber, tcp: bool = True, pty: bool = False,
                        port: int = 0) -> tuple[LineServer, dict[str, str]]:
    """Serve `chamber` in the ASCII dialect; returns the server (close it) and its URLs
    ({'tcp': 'tcp://127.0.0.1:port', 'pty': '/dev/pts/N'} as requested)."""
    return serve_lines(ChamberAsciiHandler(chamber), tcp, pty, port)


def serve_chamber(chamber: SimChamber, dialect: str, where: str = "tcp", host: str = "127.0.0.1", port: int = 0,
                  register_map: ChamberMap | None = None,
                  idle_timeout_s: float = IDLE_TIMEOUT_S) -> tuple[Callable[[], None], str]:
    """Serve `chamber` in `dialect` ('ascii' or 'modbus') on TCP (`where` 'tcp', at host:port) or a new pty
    (`where` 'pty'; Modbus RTU for modbus); returns (close, the URL a client opens)."""
    if dialect == "modbus":
        modbus = ChamberModbusServer(chamber, register_map, idle_timeout_s=idle_timeout_s)
        try:
            if where == "pty":
                return modbus.close, f"modbus+rtu://{modbus.start_rtu_pty()}?baud=115200"
            bound_host, bound_port = modbus.start_tcp(host, port)
        except BaseException:
            modbus.close()
            raise
        return modbus.close, f"modbus+tcp://{bound_host}:{bound_port}"
    if dialect != "ascii":
        raise ValueError(f"no simulated chamber for dialect {dialect!r} (ascii, modbus)")
    server = LineServer(ChamberAsciiHandler(chamber), idle_timeout_s=idle_timeout_s)
    try:
        if where == "pty":
            return server.close, server.open_pty()
        bound_host, bound_port = server.listen_tcp(host, port)
    except BaseException:
        server.close()
        raise
    return server.close, f"tcp://{bound_host}:{bound_port}"


__all__ = ["ChamberAsciiHandler", "ChamberModbusServer", "EXCEPTION_FOR_ERROR", "GARBAGE", "GenericFace",
           "NA_FOR_ERROR", "serve_chamber", "serve_chamber_ascii"]
