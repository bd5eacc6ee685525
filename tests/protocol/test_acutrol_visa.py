"""`bench sim table --dialect acutrol` driven through pyvisa with pyvisa-py (`TCPIP::127.0.0.1::PORT::SOCKET`):

- a test client written from the public real-table client's sequence (IEAv-EFO/acutrol3000, python/acutrol3000.py:
  initialise, read limits, set limits, move to a position, read status, wait for stop, run at a rate, delta move,
  check the interlock, terminate), over both framings: every reply it parses passes the checks that client makes
  (`float()`, `== "Position\\n"`, `== "Rate\\n"`, `== "Fault\\n"`, `== "65\\n"`);
- our driver through `visa://` URLs.
The public client's oscillator calls (`:mode:synt`, `:dem:osc`) are left out: synthesis mode is not simulated.
"""

from __future__ import annotations

import struct
import time

import pytest

from drivers.errors import TurntableCommandError
from drivers.turntable import open_turntable
from drivers.turntable.base import AxisMode
from tests.helpers.run import stop_process
from tests.helpers.sim_process import read_until, start_sim

pyvisa = pytest.importorskip("pyvisa")
pytest.importorskip("pyvisa_py")

WAIT_POLLS = 400          # bounds every wait for the table to stop (the simulator runs on the wall clock)


@pytest.fixture(params=["tcp", "gpib"])
def served(request):
    proc = start_sim("table", "--dialect", "acutrol", "--acl-framing", request.param, "--listen", "tcp://127.0.0.1:0")
    try:
        line = read_until(proc, "listening on")[-1]
        read_until(proc, "fault console")
        port = int(line.rsplit(":", 1)[1])
        yield request.param, port, proc
    finally:
        stop_process(proc)


class PublicClientSequence:
    """The public client's calls, over a VISA socket. `ask` returns a reply as a GPIB read hands it to that client
    (text then LF); on the framed TCP port the frame's error code must be 0 and every command is answered too."""

    def __init__(self, inst, framing: str):
        self.inst, self.framing = inst, framing
        self.replies: list[str] = []

    def _framed(self, message: str) -> str:
        self.inst.write_raw(message.encode("ascii") + b"\n")
        code, length = struct.unpack("<iI", self.inst.read_bytes(8))
        body = self.inst.read_bytes(length + 1)
        assert code == 0, f"{message!r} refused: {body!r}"
        assert body.endswith(b"\0")
        return body[:-1].decode("ascii")

    def write(self, message: str) -> None:
        if self.framing == "tcp":
            assert self._framed(message) == ""
        else:
            self.inst.write_raw(message.encode("ascii") + b"\n")

    def ask(self, message: str) -> str:
        if self.framing == "tcp":
            reply = self._framed(message) + "\n"
        else:
            self.inst.write_raw(message.encode("ascii") + b"\n")
            reply = self.inst.read_raw().decode("ascii")
            assert reply.endswith("\n") and "\n" not in reply[:-1]
        self.replies.append(reply)
        return reply

    # -- the sequence ------------------------------------------------------------------------------------------
    def status(self) -> dict[str, float]:
        pos, rate, acc = self.ask(":read:pos? 1;rate? 1;acc? 1").split(";")
        return {"pos": float(pos), "rate": float(rate), "acc": float(acc)}

    def check_error(self) -> bool:
        return self.ask(":interlock? 1") == "Fault\n" or self.ask("*stb?") == "65\n"

    def initialize(self) -> None:
        self.write(":Interlock:Reset")
        self.write(":mode:off 1")
        self.write(":int:close 1")
        self.stop()

    def stop(self) -> None:
        self.write(":mode:rate 1")
        self.write(":dem:rate 1,0")

    def terminate(self) -> None:
        self.stop()
        self.write(":int:open 1")

    def limits(self) -> dict[str, float]:
        absolute = self.ask(":limit:absolute? 1")
        assert len([float(v) for v in absolute.split(",")]) >= 6       # the six names that client prints
        return {f"{kind} {mode}": float(self.ask(f":limit:{kind}? {mode},1"))
                for kind in ("acc", "rate") for mode in ("pos", "rate", "synt")}

    def set_limits(self, acc: float, rate: float) -> None:
        for mode in ("pos", "rate", "synt"):
            self.write(f":lim:acc {mode},1,{acc}")
            self.write(f":lim:rate {mode},1,{rate}")

    def _in_mode(self, mode: str, word: str) -> None:
        if self.check_error():
            self.initialize()
        self.write(":int:close 1")
        if self.ask(":mode? 1") != f"{word}\n":
            self.write(f":mode 1,{mode}")

    def send_position(self, pos: float) -> None:
        self._in_mode("pos", "Position")
        self.write(f":dem:pos 1,{pos}")

    def send_delta_position(self, delta: float) -> None:
        self._in_mode("pos", "Position")
        self.write(f":dem:delta 1,{delta}")

    def send_rate(self, rate: float) -> None:
        self._in_mode("rate", "Rate")
        self.write(f":dem:rate 1,{rate}")

    def wait_stop(self, at_deg: float | None = None) -> dict[str, float]:
        for _ in range(WAIT_POLLS):
            state = self.status()
            if abs(state["rate"]) <= 0.01 and (at_deg is None or abs(state["pos"] - at_deg) < 1e-4):
                return state
            time.sleep(0.05)
        raise AssertionError(f"the table did not stop (last {state})")


def _fault_console(proc, command: str) -> None:
    proc.stdin.write(command + "\n")
    proc.stdin.flush()
    assert proc.stdout.readline().strip() == "ok"


@pytest.mark.slow
def test_the_public_clients_sequence_through_pyvisa(served):
    framing, port, proc = served
    manager = pyvisa.ResourceManager("@py")
    inst = manager.open_resource(f"TCPIP::127.0.0.1::{port}::SOCKET")
    try:
        inst.timeout = 5000
        inst.read_termination = "\n" if framing == "gpib" else None
        client = PublicClientSequence(inst, framing)
        assert client.ask("*idn?").startswith("turntable-bench,ACUTROL3000-SIM,")
        before = client.limits()
        assert before["rate pos"] == 200.0 and before["acc synt"] == 50.0
        client.initialize()
        client.set_limits(40, 150)
        assert client.limits() == {f"{kind} {mode}": value for kind, value in (("acc", 40.0), ("rate", 150.0))
                                   for mode in ("pos", "rate", "synt")}
        client.send_position(10)
        assert client.ask(":mode? 1") == "Position\n"
        # within what `wait_stop` waits for (1e-4 deg): where in its settling the poll lands is the machine's speed
        assert client.wait_stop(at_deg=10.0)["pos"] == pytest.approx(10.0, abs=1e-4)
        client.send_rate(-20)
        assert client.ask(":mode? 1") == "Rate\n"
        client.stop()
        rest = client.wait_stop()["pos"]
        client.send_delta_position(5)
        assert client.wait_stop(at_deg=rest + 5.0)["pos"] == pytest.approx(rest + 5.0, abs=1e-4)
        assert not client.check_error() and client.ask(":interlock? 1") == "Close\n"
        _fault_console(proc, "limit outer")
        assert client.ask(":interlock? 1") == "Fault\n" and client.ask("*stb?") == "65\n"
        assert client.check_error()
        client.initialize()                                   # what that client does on an interlock error
        assert not client.check_error()
        client.terminate()
        assert client.ask(":interlock? 1") == "Open\n"
        for reply in client.replies:                          # one reply, one line, printable
            assert reply.count("\n") == 1 and reply[:-1].isprintable()
    finally:
        inst.close()
        manager.close()


def test_our_driver_through_visa_urls(served):
    framing, port, proc = served
    url = f"visa://TCPIP::127.0.0.1::{port}::SOCKET?backend=@py"
    with open_turntable(url, "acutrol", framing=framing, timeout_s=2.0) as table:
        assert table.absolute_limits[0].rate_dps == 200.0
        table.enable()
        table.move_to([5.0, -5.0, 2.5], rate_dps=100.0)
        state = table.wait_in_position([5.0, -5.0, 2.5], tolerance_deg=1e-6, timeout_s=30.0, poll_s=0.02)
        assert state.modes == (AxisMode.POSITION,) * 3
        _fault_console(proc, "estop")
        with pytest.raises(TurntableCommandError, match="Interlock fault latched"):
            table.reset_faults()
        _fault_console(proc, "release")
        table.reset_faults()
        table.abort()
        assert not any(axis.enabled for axis in table.read_state().axes)
