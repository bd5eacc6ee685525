"""An SLCAN adapter (CANable, USBtin, ...) read in bulk: a python-can bus for high frame rates.

python-can's own `slcan` interface reads the serial port one byte per call and parses one
frame per `recv`; on the 2-core development machine that tops out near 9,700 frames/s,
below what a 2 kHz IMU sends. `BulkSlcanBus` takes everything the port holds in one read,
splits it into lines and parses every frame of the read at once (`drain_messages` hands the
whole batch to `ImuReceiver.poll`). Same channel syntax as python-can's (`/dev/ttyACM0`,
`COM8`, `/dev/ttyUSB0@115200`, or any pyserial URL such as `socket://host:port`), same
`bitrate`, `tty_baudrate`, `sleep_after_open`, `rtscts`, `listen_only` options and the same
commands on the wire (`C`, `S<n>`, `O`/`L`, ... `C` on shutdown), so either reads the same
adapter. Frames: `t`/`T` data, `r`/`R` remote, `d`/`D`/`b`/`B` CAN FD (CANable 2.0 firmware);
a 4-hex-digit adapter timestamp after the data (`Z1`) is ignored, as python-can ignores it:
frames carry the host's receive time. Lines that are no frame and no reply are counted in
`malformed_lines` and skipped.

An adapter another client left open keeps sending, and the port holds what it sent (seconds
of frames): after its `C` the bus reads and drops everything until the adapter answers that
`C` (CR, or BEL when it was closed; at most `close_ack_timeout_s`), then empties the port,
so only frames sent after its own `O` are read. Each frame of a read gets its own receive
time: a read takes what arrived since the previous one, so its frames are spread evenly, by
their place in the read, between the previous read and this one (a read that had to wait
for its first byte spans from the end of the wait only).

`open_bus` (drivers.imu.receiver) builds one for `interface = "slcan"` unless
`slcan_client = "python-can"`; `can.Bus(interface="bench_slcan", ...)` also finds it
through the `can.interface` entry point of an installed turntable-bench.
"""

from __future__ import annotations

import binascii
import os
import select
import time
from collections import deque
from typing import Any

import can
from can.util import CAN_FD_DLC, len2dlc

try:
    import serial
except ImportError:  # pragma: no cover - pyserial is a core dependency
    serial = None

#: who reads an SLCAN adapter (`[imu] slcan_client`): this module's bulk reader, or python-can's `slcan`
SLCAN_CLIENTS = ("bench", "python-can")
#: `bitrate` -> Lawicel command (python-can's table)
BITRATES = {10_000: "S0", 20_000: "S1", 50_000: "S2", 100_000: "S3", 125_000: "S4", 250_000: "S5",
            500_000: "S6", 750_000: "S7", 1_000_000: "S8", 83_300: "S9"}
#: the most one read takes from the port, bytes
READ_SIZE = 1 << 16
#: a line longer than this is garbage (the longest frame, an extended FD one with a timestamp, is 143 bytes)
MAX_LINE = 160
#: replies kept for `get_version` / `get_serial_number` while frames keep coming
MAX_REPLIES = 64
_FRAME_HEADS = frozenset(b"tTrRdDbBx")
_HEX = frozenset(b"0123456789abcdefABCDEF")


class BulkSlcanBus(can.BusABC):
    """An SLCAN adapter on a serial port, read in bulk (see the module docstring)."""

    def __init__(self, channel: str, tty_baudrate: int = 115200, bitrate: int | None = None,
                 sleep_after_open: float = 2.0, rtscts: bool = False, listen_only: bool = False,
                 timeout: float = 0.001, close_ack_timeout_s: float = 0.5, **kwargs: Any) -> None:
        if serial is None:  # pragma: no cover
            raise can.CanInterfaceNotImplementedError("the serial module (pyserial) is not installed")
        if not channel:
            raise ValueError("an SLCAN adapter needs a serial port as its channel")
        if bitrate is not None and bitrate not in BITRATES:
            raise ValueError(f"invalid SLCAN bit rate {bitrate}; choose one of {', '.join(map(str, BITRATES))}")
        port_name = str(channel)
        if "@" in port_name:
            port_name, baud = port_name.rsplit("@", 1)
            tty_baudrate = int(baud)
        self._listen_only = listen_only
        self._frames: deque[can.Message] = deque()
        self._replies: deque[bytes] = deque(maxlen=MAX_REPLIES)
        self._buffer = bytearray()
        self.malformed_lines = 0     # lines that were neither a frame nor a reply (wire garbage), skipped
        self.error_replies = 0       # BEL: the adapter refused a command
        self.acks = 0                # CR (ok) or BEL (error): the adapter answered a command
        self.stale_frames = 0        # frames sent before this bus opened the channel, dropped
        self._last_read_s = time.time()
        try:
            self._port = serial.serial_for_url(port_name, baudrate=tty_baudrate, rtscts=rtscts, timeout=timeout)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise can.CanInitializationError(f"cannot open the SLCAN port {port_name!r}: {exc}") from exc
        try:
            self._fd: int | None = self._port.fileno()
        except Exception:  # noqa: BLE001 - a URL port (socket://, loop://) or Windows: no descriptor to select on
            self._fd = None
        try:
            time.sleep(sleep_after_open)
            self._write("C")
            self._drop_until_answered(close_ack_timeout_s)
            if bitrate is not None:
                self._write(BITRATES[bitrate])
            self.open()
        except can.CanError:
            self._port.close()
            raise
        self.channel_info = f"SLCAN (bulk reader) on {port_name}"
        super().__init__(channel, **kwargs)

    # -- commands -------------------------------------------------------------------
    def _write(self, command: str) -> None:
        try:
            self._port.write(command.encode("ascii") + b"\r")
            self._port.flush()
        except (serial.SerialException, OSError) as exc:
            raise can.CanOperationError(f"cannot write to the SLCAN port: {exc}") from exc

    def open(self) -> None:
        """Open the channel: `O`, or `L` (listen only)."""
        self._write("L" if self._listen_only else "O")

    def close(self) -> None:
        """Close the channel: `C` (frames stop)."""
        self._write("C")

    def set_bitrate(self, bitrate: int) -> None:
        """Close, set the bit rate (`S<n>`), open again."""
        if bitrate not in BITRATES:
            raise ValueError(f"invalid SLCAN bit rate {bitrate}; choose one of {', '.join(map(str, BITRATES))}")
        self.close()
        self._write(BITRATES[bitrate])
        self.open()

    def _drop_until_answered(self, timeout_s: float) -> None:
        """Read and drop what the port holds until the adapter answers the command just sent (bounded), then
        empty the port: frames an adapter left open by another client sent before this bus opened it."""
        answered = self.acks
        deadline = time.monotonic() + timeout_s
        while self.acks == answered:
            left = deadline - time.monotonic()
            if left <= 0:
                break
            self._read(min(left, 0.05))
        self.stale_frames += len(self._frames)
        self._frames.clear()
        self._buffer.clear()
        try:
            self._port.reset_input_buffer()
        except (serial.SerialException, OSError) as exc:
            raise can.CanOperationError(f"cannot read from the SLCAN port: {exc}") from exc

    def flush(self) -> None:
        """Discard what was read and not taken, and what the port holds."""
        self._buffer.clear()
        self._frames.clear()
        self._port.reset_input_buffer()

    # -- reading --------------------------------------------------------------------
    def _read(self, timeout: float | None) -> bool:
        """Read what the port has (waiting up to `timeout` for a first byte) and parse it; whether anything came."""
        since = self._last_read_s
        try:
            if self._fd is not None:
                ready, _, _ = select.select([self._fd], [], [], 0.0)
                if not ready and timeout != 0.0:
                    ready, _, _ = select.select([self._fd], [], [], timeout)
                    since = time.time()          # it came during the wait: after its start
                if not ready:
                    return False
                data = os.read(self._fd, READ_SIZE)
                if not data:
                    raise can.CanOperationError("the SLCAN port was closed (end of file)")
            else:
                data = self._port.read(max(1, self._port.in_waiting))   # waits at most the port's timeout
                if not data:
                    return False
                if self._port.in_waiting:
                    data += self._port.read(self._port.in_waiting)
        except (serial.SerialException, OSError) as exc:
            raise can.CanOperationError(f"cannot read from the SLCAN port: {exc}") from exc
        now = time.time()
        self._parse(data, max(min(since, now), self._last_read_s), now)
        self._last_read_s = now
        return True

    def _parse(self, data: bytes, since: float, now: float) -> None:
        """Split `data` (after what was left over) into lines; frames to the queue, replies aside. Frames get
        receive times from `since` to `now` by the place where their line ends in `data`."""
        buffer = self._buffer
        held = len(buffer)                       # bytes of a line begun in an earlier read
        buffer += data
        if b"\a" in buffer:
            self.error_replies += buffer.count(b"\a")
            buffer[:] = buffer.replace(b"\a", b"\r")
        end = buffer.rfind(b"\r")
        if end < 0:
            if len(buffer) > MAX_LINE:
                self.malformed_lines += 1
                buffer.clear()
            return
        lines = bytes(buffer[:end]).split(b"\r")
        del buffer[:end + 1]
        frames, message, unhex, heads = self._frames, can.Message, binascii.unhexlify, _FRAME_HEADS
        span, size = now - since, max(len(data), 1)
        line_end = -held                          # where the current line ends in `data`
        for line in lines:
            line_end += len(line) + 1
            if not line:
                self.acks += 1                       # a bare CR (or BEL): a command answered
                continue
            head = line[0]
            if head == 0x0A:                         # an adapter that ends lines with CR LF
                line = line.lstrip(b"\n")
                if not line:
                    self.acks += 1
                    continue
                head = line[0]
            now = since + span * min(max(line_end, 0), size) / size
            if head not in heads:
                if head in b"VvNFzZ":
                    self._replies.append(line)
                else:
                    self.malformed_lines += 1
                continue
            try:
                if head == 0x74:                     # 't': the common case first
                    dlc = line[4] - 48
                    if not 0 <= dlc <= 8 or len(line) < 5 + 2 * dlc:
                        raise ValueError
                    frames.append(message(timestamp=now, arbitration_id=int(line[1:4], 16), is_extended_id=False,
                                          dlc=dlc, data=unhex(line[5:5 + 2 * dlc]), check=False))
                    continue
                extended = head in b"TRDBx"
                id_end = 9 if extended else 4
                can_id = int(line[1:id_end], 16)
                if head in b"rR":
                    dlc = line[id_end] - 48
                    if not 0 <= dlc <= 8:
                        raise ValueError
                    frames.append(message(timestamp=now, arbitration_id=can_id, is_extended_id=extended,
                                          is_remote_frame=True, dlc=dlc, check=False))
                    continue
                fd = head in b"dDbB"
                dlc = int(line[id_end:id_end + 1], 16) if fd else line[id_end] - 48
                length = CAN_FD_DLC[dlc] if fd else dlc
                if not 0 <= dlc <= (15 if fd else 8) or len(line) < id_end + 1 + 2 * length:
                    raise ValueError
                frames.append(message(timestamp=now, arbitration_id=can_id, is_extended_id=extended, is_fd=fd,
                                      bitrate_switch=head in b"bB", dlc=length,
                                      data=unhex(line[id_end + 1:id_end + 1 + 2 * length]), check=False))
            except (ValueError, IndexError, binascii.Error):
                self.malformed_lines += 1

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        frames = self._frames
        if not frames:
            if timeout is None:
                while not frames:
                    self._read(None)
            else:
                deadline = time.monotonic() + timeout
                while True:
                    self._read(max(0.0, deadline - time.monotonic()))
                    if frames:
                        break
                    if time.monotonic() >= deadline:
                        return None, False
        return frames.popleft(), False

    def drain_messages(self, limit: int | None = None) -> list[can.Message]:
        """Every frame read and not yet taken, after one more read of what the port has now (no waiting);
        at most `limit` (the rest stays queued). Filters set on the bus apply."""
        self._read(0.0)
        frames = self._frames
        if limit is None or limit >= len(frames):
            out = list(frames)
            frames.clear()
        else:
            out = [frames.popleft() for _ in range(limit)]
        if self._filters:
            out = [m for m in out if self._matches_filters(m)]
        return out

    # -- replies ----------------------------------------------------------------------
    def _reply(self, command: str, head: bytes, timeout: float | None) -> bytes | None:
        self._replies.clear()
        self._write(command)
        deadline = time.monotonic() + (timeout if timeout is not None else 3600.0)
        while True:
            for reply in list(self._replies):
                if reply.startswith(head):
                    return reply
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self._read(min(left, 0.05))

    def get_version(self, timeout: float | None) -> tuple[int | None, int | None]:
        """(hardware version, software version) from `V`, or (None, None) on timeout."""
        reply = self._reply("V", b"V", timeout)
        if reply is None or len(reply) < 5:
            return None, None
        try:
            return int(reply[1:3]), int(reply[3:5])
        except ValueError:
            return None, None

    def get_serial_number(self, timeout: float | None) -> str | None:
        """The adapter's serial number from `N`, or None on timeout."""
        reply = self._reply("N", b"N", timeout)
        return None if reply is None else reply[1:].decode("ascii", "replace")

    # -- sending --------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        ident = f"{msg.arbitration_id:08X}" if msg.is_extended_id else f"{msg.arbitration_id:03X}"
        if msg.is_remote_frame:
            line = ("R" if msg.is_extended_id else "r") + ident + f"{msg.dlc:d}"
        elif msg.is_fd:
            kind = ("B" if msg.is_extended_id else "b") if msg.bitrate_switch else ("D" if msg.is_extended_id else "d")
            line = kind + ident + f"{len2dlc(msg.dlc):X}" + bytes(msg.data).hex().upper()
        else:
            line = ("T" if msg.is_extended_id else "t") + ident + f"{msg.dlc:d}" + bytes(msg.data).hex().upper()
        self._port.write_timeout = timeout
        self._write(line)

    def fileno(self) -> int:
        if self._fd is None:
            raise NotImplementedError("this SLCAN port has no file descriptor")
        return self._fd

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        try:
            self.close()
        except can.CanError:
            pass                     # the port is gone already: nothing to close on it
        finally:
            self._port.close()


__all__ = ["BITRATES", "SLCAN_CLIENTS", "BulkSlcanBus"]
