"""The simulated controller served in the `$MN` checksum-framed dialect (docs/hardware/mn.md).

`MnSimHandler(controller)` is a `LineServer` handler: one request line in, one reply
frame (with CR LF) out. It decodes with the same codec the client uses, executes on
the `SimController` and applies `controller.faults` to the reply:
- timeout: the command executes, the reply is lost (nothing is sent);
- garbage: the command executes, junk bytes + CR LF are sent instead of the reply;
- checksum: the command executes, the reply's checksum digits are wrong;
- exception: nothing executes, the reply is `ERR,<faults.exception_code>`;
- late: the command executes, the reply is sent just before the reply to the next line.
A request whose checksum is wrong is answered `ERR,7` and not executed; one that cannot
be read at all is answered with command `ERR` (`$ASERR,ERR,1`).

    server = LineServer(MnSimHandler(SimController()))
    host, port = server.listen_tcp()      # or: path = server.open_pty()
"""

from __future__ import annotations

import re

from bench.sim.controller import ERR_FAULT, ERR_NOT_ENABLED, ERR_WRONG_MODE, SimCommandError, SimController
from bench.sim.serve import LineServer, held_first, reply_with_fault
from drivers.errors import DeviceProtocolError
from drivers.turntable import mn_codec as codec
from drivers.turntable.base import FRAMES, AxisMode, AxisStatus

GARBAGE = b"\x00\xff#%&garbage\x1b[0m?"
_CMD_HINT = re.compile(rb"\$MN([A-Z]{3})[,*]")


def _wrong_checksum(reply: bytes) -> bytes:
    """A reply frame (with its terminator) with wrong checksum digits."""
    frame = reply[:-len(codec.TERMINATOR)]
    wrong = (int(frame[-2:], 16) + 0x5A) & 0xFF
    return frame[:-2] + f"{wrong:02X}".encode("ascii") + codec.TERMINATOR


class MnSimHandler:
    """`(line: bytes) -> bytes | None`: the `$MN` face of a SimController."""

    def __init__(self, controller: SimController):
        self.controller = controller

    def __call__(self, line: bytes) -> bytes | None:
        return held_first(self.controller.faults, lambda: self._faulty_reply(line))

    def _faulty_reply(self, line: bytes) -> bytes | None:
        hint = _CMD_HINT.match(line)
        cmd = hint.group(1).decode("ascii") if hint else codec.UNREADABLE_CMD
        return reply_with_fault(self.controller.faults, lambda: self.reply(line) + codec.TERMINATOR,
                                exception_reply=lambda code: codec.encode_error(cmd, code) + codec.TERMINATOR,
                                garbage=GARBAGE + codec.TERMINATOR, corrupt=_wrong_checksum)

    def reply(self, line: bytes) -> bytes:
        """Decode and execute one request; its reply frame (no terminator, no injected fault)."""
        try:
            request = codec.decode_request(line)
        except codec.MnChecksumError:
            hint = _CMD_HINT.match(line)
            return codec.encode_error(hint.group(1).decode("ascii") if hint else codec.UNREADABLE_CMD,
                                      codec.ERR_CHECKSUM)
        except codec.MnRequestError as exc:
            hint = _CMD_HINT.match(line)
            return codec.encode_error(hint.group(1).decode("ascii") if hint else codec.UNREADABLE_CMD, exc.code)
        except DeviceProtocolError:
            return codec.encode_error(codec.UNREADABLE_CMD, codec.ERR_SYNTAX)
        try:
            return self._execute(request)
        except SimCommandError as exc:
            return codec.encode_error(request.cmd, exc.code)
        except ValueError:      # a value the table model rejects: refuse it, keep serving
            return codec.encode_error(request.cmd, codec.ERR_ARGUMENT)

    def _execute(self, request: codec.Request) -> bytes:
        ctl = self.controller
        if isinstance(request, codec.Check):
            if request.station != 1:
                raise SimCommandError(f"no station {request.station}", codec.ERR_ARGUMENT)
        elif isinstance(request, codec.Enable):
            for k in request.axes:
                ctl.enable(k)
        elif isinstance(request, codec.Disable):
            for k in request.axes:
                ctl.disable(k)
        elif isinstance(request, codec.Reset):
            for k in request.axes:
                ctl.reset(k)
        elif isinstance(request, codec.SetMode):
            ctl.set_mode(request.axis, request.mode)
        elif isinstance(request, codec.MovePositions):
            self._move(request)
        elif isinstance(request, codec.SetRate):
            ctl.demand_rate(request.axis, request.rate_dps)
        elif isinstance(request, codec.Stop):
            ctl.stop()
        elif isinstance(request, codec.Abort):
            ctl.abort()
        elif isinstance(request, codec.ReadState):
            return codec.encode_state(ctl.state())
        return codec.encode_ok(request.cmd)

    def _move(self, request: codec.MovePositions) -> None:
        """All targeted axes or none: check each before the first one starts moving."""
        ctl = self.controller
        state = ctl.state()
        targeted = [(k, t) for k, t in enumerate(request.targets_deg) if t is not None]
        for k, target in targeted:
            axis = state.axes[k]
            if axis.status & (AxisStatus.ESTOP | AxisStatus.FAULT | AxisStatus.LIMIT):
                raise SimCommandError(f"{FRAMES[k]} axis has a latched fault; reset first", ERR_FAULT)
            if not axis.enabled:
                raise SimCommandError(f"{FRAMES[k]} axis is not enabled", ERR_NOT_ENABLED)
            if axis.mode is not AxisMode.POSITION:
                raise SimCommandError(f"{FRAMES[k]} axis is in {axis.mode.value} mode", ERR_WRONG_MODE)
            lim = ctl.limits[k]
            rate = request.rates_dps[k]
            if (lim.min_deg is not None and target < lim.min_deg) or (lim.max_deg is not None and target > lim.max_deg):
                raise SimCommandError(f"{FRAMES[k]} position {target} outside travel", codec.ERR_LIMIT)
            if rate is not None and not 0 < rate <= lim.max_rate_dps:
                raise SimCommandError(f"{FRAMES[k]} move rate {rate} outside (0, {lim.max_rate_dps}]",
                                      codec.ERR_LIMIT if rate > 0 else codec.ERR_ARGUMENT)
        for k, target in targeted:
            ctl.demand_position(k, target, request.rates_dps[k])


def serve_mn(controller: SimController) -> LineServer:
    """A LineServer for `controller` in the $MN dialect (call `listen_tcp()` / `open_pty()` on it)."""
    return LineServer(MnSimHandler(controller))
