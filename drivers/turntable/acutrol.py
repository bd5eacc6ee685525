"""Client of an ACUTROL3000 controller in its Command Language (ACL, Acutronic TM-8004); see docs/hardware/acutrol.md.

Transports: `tcp://host[:port]` (the controller's ACL port, 9878 by default, TM-9384C), a serial device or
any pyserial URL (an RS-232 device server bridges to that port, TM-9411), and `visa://RESOURCE` through
pyvisa (optional extra). On TCP and serial every program message gets one framed response carrying an
error code (TM-8004 ch. 2), so each command is confirmed by its own response. A GPIB instrument
(`visa://GPIB0::1::INSTR`) answers queries only: there a command is followed by a read of the error
queue (`:STAT:MSG? QERROR`), empty when the command was taken.

On connect the client reads the controller's absolute (factory) limits of every axis; configured limits
beyond them are refused there, and a demand beyond them is refused before anything is sent.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Callable, Sequence, TypeVar
from urllib.parse import urlsplit

from drivers.clock import SYSTEM_CLOCK, Clock
from drivers.errors import (
    DeviceConnectionError,
    DeviceTimeout,
    TurntableCommandError,
    TurntableConfigError,
    TurntableConnectionError,
    TurntableLimitError,
    TurntableProtocolError,
)
from drivers.transport import ByteTransport, LineChannel
from drivers.turntable import acutrol_codec as ac
from drivers.turntable.base import (
    FRAMES,
    AxisMode,
    AxisState,
    AxisStatus,
    TableState,
    TurntableLimits,
    frame_index,
)
from drivers.turntable.line_client import LineTurntable
from drivers.visa_transport import VisaTransport, is_message_based_gpib, is_visa_url

DEFAULT_PORT = 9878
MOVING_RATE_DPS = 1e-3     # an unservoed axis turning faster than this is moving
T = TypeVar("T")

# status register bits read for the state (TM-8004 appendix B)
INTLK_PA_ACK, INTLK_LIMIT_STRING, INTLK_MASTER = 1 << 6, 1 << 7, 1 << 9
DYN_POSITION_COMPLETE, DYN_RATE_COMPLETE = 1 << 8, 1 << 9
_INTLK_WORDS = {INTLK_PA_ACK: "amplifier acknowledge lost (PA_ACK0)", INTLK_LIMIT_STRING:
                "limit switch string open (INTLK1)", INTLK_MASTER: "master interlock open"}


class FramedChannel(LineChannel):
    """`read_line` returns one whole framed response (header, text, NUL) instead of a line."""

    def read_line(self, timeout_s: float) -> bytes | None:
        deadline = time.monotonic() + timeout_s

        def read_exactly(count: int) -> bytes | None:
            while len(self._buffer) < count:
                remaining = deadline - time.monotonic()
                if remaining <= 0:
                    return None
                self._buffer += self.transport.read(count - len(self._buffer), remaining)
            out = bytes(self._buffer[:count])
            del self._buffer[:count]
            return out

        head = read_exactly(ac.HEADER.size)
        if head is None:
            return None
        size = ac.frame_size(head)
        if size is None:                         # not a frame: what follows cannot be told apart from the next one
            self.discard_input()
            return head                          # for parse_framed to refuse
        rest = read_exactly(size - ac.HEADER.size)
        if rest is None:
            self._buffer[:0] = head              # not all there yet: a late read may complete it
            return None
        return head + rest


def _with_default_port(url: str) -> str:
    if url.startswith("tcp://"):
        parts = urlsplit(url)
        if parts.port is None and parts.hostname and not parts.path.strip("/") and not parts.query:
            return f"tcp://{parts.netloc}:{DEFAULT_PORT}"
    return url


class AcutrolTurntable(LineTurntable):
    """An ACUTROL3000 controller; `framing` 'tcp' (framed responses) or 'gpib' (answers to queries only),
    chosen from the URL when None. `long_form=True` sends long mnemonics (`:DEMAND:POSITION`)."""

    dialect = "acutrol"
    terminator = b"\n"

    def __init__(self, transport: ByteTransport | str, limits: TurntableLimits | None = None,
                 clock: Clock = SYSTEM_CLOCK, timeout_s: float = 0.5, retries: int = 2, long_form: bool = False,
                 framing: str | None = None):
        if isinstance(transport, str):
            transport = _with_default_port(transport)
            if framing is None:
                framing = "gpib" if is_visa_url(transport) and is_message_based_gpib(transport) else "tcp"
            if is_visa_url(transport):
                transport = VisaTransport(transport, line_mode=framing == "gpib")
        framing = framing or "tcp"
        if framing not in ("tcp", "gpib"):
            raise TurntableConfigError(f"acutrol framing must be 'tcp' or 'gpib', got {framing!r}")
        super().__init__(transport, limits, clock, timeout_s, retries)
        self.framing, self.long_form = framing, long_form
        if framing == "tcp":
            self.channel = FramedChannel(self.transport)
        self.configured_limits = self.limits
        self.absolute_limits: tuple[ac.AbsoluteLimits, ...] = ()

    # -- messages -----------------------------------------------------------------------------------------------
    def _unit(self, path: str, *args: object, query: bool = False) -> str:
        return ac.unit(path, *args, query=query, long_form=self.long_form)

    def _exchange(self, units: Sequence[str], parse: Callable[[str, bytes], T] | None = None) -> T | None:
        """Send one program message; `parse(text, raw)` its query responses (None: commands only). An ACL
        error -> TurntableCommandError naming the message sent and the controller's text."""
        sent = ac.message(*units)
        if self.framing == "tcp":
            def parse_frame(frame: bytes) -> T | None:
                response = ac.parse_framed(frame)
                if response.code != ac.NO_ERROR:
                    raise self._refusal(sent, response.code, response.text)
                return parse(response.text, frame) if parse is not None else None
            return self._transact(sent, parse_frame)
        if parse is None:
            self._write_command(sent)
            self._raise_queued(sent)
            return None
        try:
            return self._transact(sent, lambda line: parse(line.decode("ascii", "replace"), line))
        except DeviceTimeout:
            self._raise_queued(sent)        # a refused query is not answered: the error queue says why
            raise

    def _ask(self, units: Sequence[str], parse: Callable[[str, bytes], T]) -> T:
        """`_exchange` of a message with queries: their parsed responses."""
        found = self._exchange(units, parse)
        assert found is not None, "a parse function returned None"
        return found

    def _write_command(self, sent: bytes) -> None:
        """GPIB framing: a message that gets no answer, sent on a link reopened once if it was lost."""
        for attempt in range(2):
            try:
                if not self.transport.is_open:
                    self.stats.reconnects += 1
                    self._open()
                self.channel.write_line(sent, self.terminator)
                return
            except DeviceConnectionError:
                raise
            except ConnectionError as exc:
                self.transport.close()
                if attempt:
                    raise TurntableConnectionError(f"acutrol link {self.url} lost: {exc}") from exc

    def _open(self) -> None:
        super()._open()
        if self.framing == "gpib":      # errors left on the queue by another host must not be taken for ours
            try:
                self.channel.write_line(b"*CLS", self.terminator)
            except ConnectionError as exc:
                self.transport.close()
                raise TurntableConnectionError(f"acutrol: {exc}") from exc

    def _refusal(self, sent: bytes, code: int, text: str) -> TurntableCommandError:
        why = text or ac.ERROR_TEXT.get(code, f"error {code}")
        command = sent.decode("ascii", "replace")     # our own message, shown whole: it names the unit at fault
        return TurntableCommandError(f"acutrol controller refused {command!r}: {why} (error {code})", code)

    def _raise_queued(self, sent: bytes) -> None:
        """GPIB framing: the oldest error-queue entry, raised as the refusal of `sent`. The status byte is asked in
        the same message so that the answer is never an empty line (an empty queue answers an empty string)."""
        ask = ac.message(self._unit("STATUS:MSG", "QERROR", query=True), self._unit("STATUS:STB", query=True))

        def parse(line: bytes) -> str:
            entry, _, stb = line.decode("ascii", "replace").rpartition(";")
            ac.decode_register(stb, "status byte", line)
            return entry.strip()

        entry = self._transact(ask, parse)
        if entry:
            code_text, _, text = entry.partition(",")
            code = int(code_text) if code_text.strip().lstrip("-").isdigit() else None
            raise self._refusal(sent, code if code is not None else -1, text.strip().strip('"'))

    # -- connect: the factory limits ------------------------------------------------------------------------------
    def connect(self) -> "AcutrolTurntable":
        with self._lock:
            self._open()
            try:
                self._read_absolute_limits()
            except BaseException:
                self._close()
                raise
        return self

    def _read_absolute_limits(self) -> None:
        units = [self._unit("LIMIT:ABSOLUTE", k, query=True) for k in (1, 2, 3)]

        def parse(text: str, raw: bytes) -> tuple[ac.AbsoluteLimits, ...]:
            return tuple(ac.decode_absolute_limits(f, raw) for f in ac.split_responses(text, 3, "absolute limits", raw))

        found = self._ask(units, parse)
        self.absolute_limits = found
        self.limits = merge_limits(self.configured_limits, found)

    # -- the Turntable interface ----------------------------------------------------------------------------------
    def _axes_units(self, path: str, frames: Sequence[int]) -> list[str]:
        return [self._unit(path, k + 1) for k in dict.fromkeys(frames)]

    def _enable(self, frames: Sequence[int]) -> None:
        if frames:      # closed in Off mode (zero rate), as the controller's own initialisation is done
            self._exchange(self._axes_units("MODE:OFF", frames) + self._axes_units("INTERLOCK:CLOSE", frames))

    def _disable(self, frames: Sequence[int]) -> None:
        if frames:
            self._exchange(self._axes_units("INTERLOCK:OPEN", frames))

    def _reset_faults(self, frames: Sequence[int]) -> None:
        if frames:      # the controller's reset has no axis: it clears every latched axis
            self._exchange([self._unit("INTERLOCK:RESET")])

    def _set_mode(self, frame: int, mode: AxisMode) -> None:
        k = frame + 1
        if mode is AxisMode.OFF:
            self._exchange([self._unit("MODE:OFF", k)])
            return
        # ACL takes modes and demands on an axis that is not servoed (they apply when it is): the interlock state
        # stops a demand that would not move the table (or would move it later, unasked)
        if mode is AxisMode.POSITION:
            interlock = self._ask([self._unit("MODE:POSITION", k), self._unit("INTERLOCK", k, query=True)],
                                  lambda text, raw: ac.decode_interlock(text, raw))
            self._require_servoed(frame, interlock)
            return
        mode_now, interlock = self._ask([self._unit("MODE", k, query=True), self._unit("INTERLOCK", k, query=True)],
                                        _mode_and_interlock)
        self._require_servoed(frame, interlock)
        if mode_now != "Rate":      # entered at zero rate: a rate demand left from before must not apply
            self._exchange([self._unit("DEMAND:RATE", k, 0.0), self._unit("MODE:RATE", k)])

    @staticmethod
    def _require_servoed(frame: int, interlock: str) -> None:
        if interlock != "Close":
            raise TurntableCommandError(f"acutrol controller: {FRAMES[frame]} axis not servoed (interlock "
                                        f"{interlock}), nothing demanded", ac.NOT_SERVOED)

    def _demand_positions(self, targets: dict[int, float], rate_dps: dict[int, float]) -> None:
        units = []
        for k, angle in targets.items():
            units += [self._unit("LIMIT:RATE", "P", k + 1, float(rate_dps[k])),
                      self._unit("DEMAND:POSITION", k + 1, float(angle))]
        self._exchange(units)

    def _demand_rate(self, frame: int, rate_dps: float) -> None:
        self._exchange([self._unit("DEMAND:RATE", frame + 1, float(rate_dps))])

    def _stop(self) -> None:
        self._exchange(self._axes_units("MODE:OFF", (0, 1, 2)))

    def _abort(self) -> None:
        self._exchange(self._axes_units("INTERLOCK:OPEN", (0, 1, 2)))

    def _read_state(self) -> TableState:
        units = ([self._unit("READ:POSITION", k, query=True) for k in (1, 2, 3)]
                 + [self._unit("READ:RATE", k, query=True) for k in (1, 2, 3)]
                 + [self._unit("MODE", k, query=True) for k in (1, 2, 3)]
                 + [self._unit("INTERLOCK", k, query=True) for k in (1, 2, 3)]
                 + [self._unit("STATUS:CSR", f"A{k}INTLK", query=True) for k in (1, 2, 3)]
                 + [self._unit("STATUS:CSR", f"A{k}DYN", query=True) for k in (1, 2, 3)])
        return self._ask(units, lambda text, raw: decode_state(text, raw, self.clock.now()))

    # -- single reads (diagnostics and the public client's sequence) -----------------------------------------------
    def _query(self, path: str, *args: object, what: str) -> str:
        with self._lock:
            return self._ask([self._unit(path, *args, query=True)],
                             lambda text, raw: ac.split_responses(text, 1, what, raw)[0])

    def identify(self) -> str:
        """`*IDN?`: maker,model,serial,software level."""
        return self._query("*IDN", what="*IDN?")

    def read_position(self, frame: int | str) -> float:
        return ac.decode_number(self._query("READ:POSITION", frame_index(frame) + 1, what="position"), "position")

    def read_rate(self, frame: int | str) -> float:
        return ac.decode_number(self._query("READ:RATE", frame_index(frame) + 1, what="rate"), "rate")

    def read_acceleration(self, frame: int | str) -> float:
        return ac.decode_number(self._query("READ:ACCELERATION", frame_index(frame) + 1, what="acceleration"),
                                "acceleration")

    def interlock_state(self, frame: int | str) -> str:
        """`:INT? n`: Close, Open or Fault."""
        return ac.decode_interlock(self._query("INTERLOCK", frame_index(frame) + 1, what="interlock"))

    def status_byte(self) -> int:
        """`:STAT:STB?`: the status byte (bit 0 system interlocks, 7 error queue, 6 summary); not cleared."""
        return ac.decode_register(self._query("STATUS:STB", what="status byte"), "status byte")

    def read_errors(self) -> list[str]:
        """Every entry of the controller's error queue (`:STAT:MSG? QERROR,ALL;:STAT:STB?`), oldest first; the queue
        empties."""
        # the status byte comes along so that an empty queue is never an empty answer (an empty line on GPIB)
        units = [self._unit("STATUS:MSG", "QERROR", "ALL", query=True), self._unit("STATUS:STB", query=True)]

        def parse(text: str, raw: bytes) -> list[str]:
            entries, _, stb = text.rpartition(";")
            ac.decode_register(stb, "status byte", raw)
            return [entry for entry in entries.split(";") if entry]

        with self._lock:
            return self._ask(units, parse)


def _mode_and_interlock(text: str, raw: bytes) -> tuple[str, str]:
    mode, interlock = ac.split_responses(text, 2, "mode and interlock", raw)
    return ac.decode_mode(mode, raw), ac.decode_interlock(interlock, raw)


def merge_limits(configured: TurntableLimits, absolute: Sequence[ac.AbsoluteLimits]) -> TurntableLimits:
    """The limits demands are checked against: the configured ones, inside the controller's absolute ones.
    A configured limit beyond an absolute one -> TurntableLimitError naming both (refused before anything moves)."""
    axes = []
    for k, (mine, factory) in enumerate(zip(configured.axes, absolute)):
        name = FRAMES[k]
        for what, value, ceiling, unit in (("max_rate_dps", mine.max_rate_dps, factory.rate_dps, "deg/s"),
                                           ("max_accel_dps2", mine.max_accel_dps2, factory.accel_dps2, "deg/s^2")):
            if value > ceiling:
                raise TurntableLimitError(f"{name} {what} {value} exceeds the controller's absolute limit "
                                          f"{ceiling} {unit}")
        if mine.min_deg is not None and mine.min_deg < factory.pos_lo_deg:
            raise TurntableLimitError(f"{name} min_deg {mine.min_deg} is below the controller's absolute low "
                                      f"position limit {factory.pos_lo_deg} deg")
        if mine.max_deg is not None and mine.max_deg > factory.pos_hi_deg:
            raise TurntableLimitError(f"{name} max_deg {mine.max_deg} is above the controller's absolute high "
                                      f"position limit {factory.pos_hi_deg} deg")
        low = factory.pos_lo_deg if mine.min_deg is None else mine.min_deg
        high = factory.pos_hi_deg if mine.max_deg is None else mine.max_deg
        axes.append(dataclasses.replace(mine, min_deg=low, max_deg=high))
    return TurntableLimits((axes[0], axes[1], axes[2]))


def decode_state(text: str, raw: bytes, time_s: float) -> TableState:
    """The 18 responses of the state read -> TableState (see docs/hardware/acutrol.md, "State")."""
    fields = ac.split_responses(text, 18, "state read", raw)
    axes, faults = [], []
    for k in range(3):
        angle = ac.decode_number(fields[k], f"axis {k + 1} position", raw)
        rate = ac.decode_number(fields[3 + k], f"axis {k + 1} rate", raw)
        mode_name = ac.decode_mode(fields[6 + k], raw)
        mode = ac.AXIS_MODE.get(mode_name)
        if mode is None:
            raise TurntableProtocolError(f"axis {k + 1} is in {mode_name} mode, which this client does not drive",
                                         raw)
        interlock = ac.decode_interlock(fields[9 + k], raw)
        intlk = ac.decode_register(fields[12 + k], f"A{k + 1}INTLK", raw)
        dyn = ac.decode_register(fields[15 + k], f"A{k + 1}DYN", raw)
        status = AxisStatus(0)
        servoed = interlock == "Close"
        if servoed:
            status |= AxisStatus.ENABLED
        complete = dyn & (DYN_POSITION_COMPLETE if mode is AxisMode.POSITION else DYN_RATE_COMPLETE)
        if (servoed and not complete) or abs(rate) >= MOVING_RATE_DPS:
            status |= AxisStatus.MOVING
        elif servoed and mode is AxisMode.POSITION:
            status |= AxisStatus.IN_POSITION
        if intlk & INTLK_LIMIT_STRING:
            status |= AxisStatus.LIMIT
        if intlk & INTLK_MASTER:
            status |= AxisStatus.ESTOP
        if interlock == "Fault" and (intlk & ~(INTLK_LIMIT_STRING | INTLK_MASTER) or not intlk):
            status |= AxisStatus.FAULT
        words = [word for bit, word in _INTLK_WORDS.items() if intlk & bit]
        if interlock == "Fault":
            faults.append(f"{FRAMES[k]}: interlock fault" + (f" ({', '.join(words)})" if words else ""))
        if not math.isfinite(angle) or not math.isfinite(rate):
            raise TurntableProtocolError(f"axis {k + 1}: a non-finite reading", raw)
        axes.append(AxisState(angle, rate, mode, status))
    return TableState(time_s, (axes[0], axes[1], axes[2]), "; ".join(faults))


__all__ = ["AcutrolTurntable", "FramedChannel", "decode_state", "merge_limits"]
