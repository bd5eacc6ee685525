"""A simulated SLCAN adapter (what USB-CAN adapters such as CANable or USBtin speak) on a pty.

python-can opens it with its own client, `can.Bus(interface="slcan", channel="/dev/pts/N")`.
The protocol is Lawicel's serial-line CAN as CANable firmware answers it: ASCII commands
ending in CR, each answered with CR (ok) or BEL (error), and the bus's frames sent to the
host as they arrive:

    O / L       open the channel (normal / listen-only): frames flow      -> \\r  (\\a if already open)
    C           close the channel: frames stop                            -> \\r
    S0..S8      bit rate 10k..1M (only while closed)                      -> \\r  (\\a while open or unknown)
    Z0 / Z1     frame timestamps off / on (4 hex digits, ms modulo 60000) -> \\r
    V / v / N   hardware+software version, firmware version, serial       -> V1013\\r, vCANBENCH\\r, NA123\\r
    F           status flags                                              -> F00\\r
    t.. T.. r.. R..  transmit a frame (only while open, not listen-only)  -> z\\r / Z\\r
    (empty)     python-can sends one for "no data bit rate"               -> \\r
    anything else (s BTR registers, Y data bit rates, d/D/b/B FD frames)  -> \\a

A received frame goes to the host as `t<id:3 hex><dlc><data hex>\\r` (11-bit id) or
`T<id:8 hex><dlc><data hex>\\r` (29-bit id). SLCAN has no CAN FD frames here (CANable 1
firmware): `encode_frame` refuses one. `SlcanPeer` is the pure state machine (bytes in,
bytes out); `SlcanPtyServer` serves it on the master side of a pty from a thread.
"""

from __future__ import annotations

import fcntl
import os
import select
import termios
import threading
import time
import tty
from collections.abc import Iterable

import can

OK = b"\r"
ERROR = b"\a"
#: `S<n>` -> bit rate, bit/s (Lawicel; python-can's slcan client sends these)
BITRATES = {"S0": 10_000, "S1": 20_000, "S2": 50_000, "S3": 100_000, "S4": 125_000, "S5": 250_000,
            "S6": 500_000, "S7": 750_000, "S8": 1_000_000}
#: `V`: hardware 1.0, software 1.3 (python-can reads two decimal digits each)
VERSION_REPLY = b"V1013\r"
FIRMWARE_REPLY = b"vCANBENCH\r"
#: bytes queued for a host that does not read (an adapter's and the USB host's buffers), then frames drop:
#: about 10 s of a 1000-frame/s stream
MAX_PENDING_BYTES = 256 * 1024
MAX_LINE = 64              # longer than any SLCAN command: junk is cut there and answered as an error


class SlcanError(ValueError):
    """A frame SLCAN cannot carry (CAN FD, more than 8 bytes)."""


def encode_frame(msg: can.Message, timestamp_ms: int | None = None) -> bytes:
    """One received frame as the adapter sends it to the host (with a timestamp when Z1 is on)."""
    if msg.is_fd:
        raise SlcanError("SLCAN carries classic CAN frames only, not CAN FD: use a classic (fd = false) layout, "
                         "or serve the IMU over socketcan")
    data = bytes(msg.data)
    if len(data) > 8:
        raise SlcanError(f"a classic CAN frame has at most 8 data bytes, got {len(data)}")
    if msg.is_remote_frame:
        head = (f"R{msg.arbitration_id:08X}{msg.dlc:d}" if msg.is_extended_id
                else f"r{msg.arbitration_id:03X}{msg.dlc:d}")
        body = ""
    else:
        head = (f"T{msg.arbitration_id:08X}{len(data):d}" if msg.is_extended_id
                else f"t{msg.arbitration_id:03X}{len(data):d}")
        body = data.hex().upper()
    stamp = "" if timestamp_ms is None else f"{timestamp_ms % 60000:04X}"
    return (head + body + stamp).encode("ascii") + OK


def _is_hex(text: str) -> bool:
    return all(c in "0123456789abcdefABCDEF" for c in text)


def _valid_transmit(line: str) -> bool:
    """A well-formed `t`, `T`, `r` or `R` command (id, dlc 0..8, data of that length)."""
    id_len = 8 if line[0] in "TR" else 3
    head = line[1:1 + id_len + 1]
    if len(head) != id_len + 1 or not _is_hex(head[:-1]) or not head[-1].isdigit():
        return False
    dlc = int(head[-1])
    data = line[2 + id_len:]
    if dlc > 8 or int(head[:-1], 16) >= (1 << (29 if id_len == 8 else 11)):
        return False
    return data == "" if line[0] in "rR" else (len(data) == 2 * dlc and _is_hex(data))


class SlcanPeer:
    """The adapter's command state machine: `handle(line)` -> reply bytes; `is_open` says whether frames flow."""

    def __init__(self, serial: str = "A123") -> None:
        self.serial_reply = b"N" + serial.encode("ascii") + b"\r"    # what `N` answers (a rig answers its id)
        self.is_open = False
        self.listen_only = False
        self.bitrate: int | None = None
        self.timestamps = False
        self.transmitted: list[str] = []     # frames the host asked to send (kept for tests, bounded)

    def handle(self, line: bytes) -> bytes:
        try:
            text = line.decode("ascii")
        except UnicodeDecodeError:
            return ERROR
        if text == "":
            return OK
        cmd = text[0]
        if cmd in "OL" and len(text) == 1:
            if self.is_open:
                return ERROR
            self.is_open, self.listen_only = True, cmd == "L"
            return OK
        if text == "C":
            self.is_open = False
            return OK
        if text in BITRATES:
            if self.is_open:
                return ERROR
            self.bitrate = BITRATES[text]
            return OK
        if text in ("Z0", "Z1"):
            if self.is_open:
                return ERROR
            self.timestamps = text == "Z1"
            return OK
        if text == "V":
            return VERSION_REPLY
        if text == "v":
            return FIRMWARE_REPLY
        if text == "N":
            return self.serial_reply
        if text == "F":
            return b"F00\r"
        if cmd in "tTrR":
            if not (self.is_open and not self.listen_only and _valid_transmit(text)):
                return ERROR
            if len(self.transmitted) < 1000:
                self.transmitted.append(text)
            return b"Z\r" if cmd in "TR" else b"z\r"
        return ERROR


def split_commands(buffer: bytearray) -> list[bytes]:
    """Pop every CR-terminated command off the front of `buffer` (LF ignored; overlong junk cut)."""
    out: list[bytes] = []
    while True:
        end = buffer.find(b"\r")
        if end < 0:
            if len(buffer) > MAX_LINE:
                out.append(bytes(buffer[:MAX_LINE]))
                del buffer[:]
            return out
        out.append(bytes(buffer[:end]).replace(b"\n", b""))
        del buffer[:end + 1]


class SlcanPtyServer:
    """Serves a `SlcanPeer` on a pty until `close()`; `send(messages)` puts bus frames on it while open.

    The pty survives its clients: one that closes the channel (`C`, as python-can does on
    shutdown) or just goes away (the pty hangs up) leaves the channel closed, and what was
    still queued for it is discarded, so the next client starts with fresh frames.
    Frames wait in a bounded queue while the host does not read (a busy process); beyond
    `MAX_PENDING_BYTES` they are dropped and counted.
    """

    def __init__(self, peer: SlcanPeer | None = None):
        self.peer = peer if peer is not None else SlcanPeer()
        self.frames_sent = 0         # queued for the host
        self.frames_dropped = 0      # not queued: the host did not read for a long time (the queue was full)
        self.clients = 0             # how many times the channel was opened
        self.peak_pending = 0        # the longest the queue for the host has been, bytes
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._t0 = time.monotonic()
        self._pending = bytearray()  # what the host has not taken yet (the adapter's and USB's buffers)
        master, slave = os.openpty()
        tty.setraw(slave)            # no echo, no CR/LF translation
        self.path = os.ttyname(slave)
        os.close(slave)              # no slave of our own: a client that goes away is seen as a hang-up
        flags = fcntl.fcntl(master, fcntl.F_GETFL)
        fcntl.fcntl(master, fcntl.F_SETFL, flags | os.O_NONBLOCK)
        self._master = master
        self._thread = threading.Thread(target=self._loop, daemon=True, name="sim-slcan-pty")
        self._thread.start()

    def send(self, messages: Iterable[can.Message]) -> None:
        """Frames on the bus: queued for the host while the channel is open, else nothing (as an adapter)."""
        with self._lock:
            if not self.peer.is_open:
                return
            stamp = (lambda: int((time.monotonic() - self._t0) * 1000)) if self.peer.timestamps else (lambda: None)
            data = b"".join(encode_frame(m, stamp()) for m in messages)
            count = data.count(OK)
            if len(self._pending) + len(data) > MAX_PENDING_BYTES:
                self.frames_dropped += count
                return
            self._pending += data
            self.frames_sent += count
            self._flush()
            self.peak_pending = max(self.peak_pending, len(self._pending))

    def _flush(self) -> None:
        """Write what the pty takes now (under the lock; the rest waits for the loop)."""
        if not self._pending:
            return
        try:
            written = os.write(self._master, self._pending)
        except OSError:              # full (EAGAIN), or nobody there (EIO: the loop sees the hang-up)
            return
        del self._pending[:written]

    def _reply(self, reply: bytes) -> None:
        """A reply goes after the frames already queued, never inside one."""
        with self._lock:
            self._pending += reply
            self._flush()

    def _hang_up(self) -> None:
        """No client has the pty open: close the channel and discard what it did not read."""
        with self._lock:
            self.peer.is_open = False
            self._pending.clear()
            try:
                own = os.open(self.path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
            except OSError:
                return
            try:
                termios.tcflush(own, termios.TCIFLUSH)
            except termios.error:
                pass
            finally:
                os.close(own)

    def _loop(self) -> None:
        poller = select.poll()
        poller.register(self._master, select.POLLIN)
        buffer = bytearray()
        hung_up = True
        while not self._stop.is_set():
            with self._lock:
                waiting = bool(self._pending)
            poller.modify(self._master, select.POLLIN | (select.POLLOUT if waiting else 0))
            events = poller.poll(20 if waiting else 100)
            if not events:
                continue
            if events[0][1] & select.POLLHUP:
                if not hung_up:
                    hung_up = True
                    buffer.clear()
                    self._hang_up()
                self._stop.wait(0.05)      # nobody there: look again soon
                continue
            hung_up = False
            if events[0][1] & select.POLLOUT:
                with self._lock:
                    self._flush()
            if not events[0][1] & select.POLLIN:
                continue
            try:
                chunk = os.read(self._master, 4096)
            except BlockingIOError:
                continue
            except OSError:
                self._stop.wait(0.05)
                continue
            buffer += chunk
            for command in split_commands(buffer):
                with self._lock:
                    was_open = self.peer.is_open
                    reply = self.peer.handle(command)
                    if self.peer.is_open and not was_open:
                        self.clients += 1
                self._reply(reply)

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        try:
            os.close(self._master)
        except OSError:
            pass

    def __enter__(self) -> "SlcanPtyServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


__all__ = ["SlcanError", "SlcanPeer", "SlcanPtyServer", "encode_frame", "split_commands"]
