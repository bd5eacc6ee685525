"""One device error root (issue 28, item 4): every error a driver raises is a `DeviceError`, under one of its
kinds, and the boundaries (the CLI's backstop, the TUI's operator commands) catch it by construction.

The hand-kept lists this replaces had drifted: the TUI's list of operator errors lacked the chamber's
tree, so a chamber alarm or a garbled chamber reply at the start of a plan ended the app with a traceback.
"""

from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

import bench.cli.evaluate
import drivers
import drivers.errors as errors
from bench.cli.common import ExitCode
from bench.cli.main import main
from bench.tui.session import OPERATOR_ERRORS
from drivers.errors import ChamberAlarm, DeviceConfigError, DeviceError
from tests.helpers.tui import SIZE, connected, dialog_open, events_text, make_app, press, run, wait_until

#: exception classes defined in drivers/ that are not driver errors, and why
NOT_DEVICE_ERRORS = {
    "drivers.turntable.acutrol_codec.AclError": "the controller side's refusal: the simulator answers it on the wire",
    "drivers.chamber.ascii_codec.RequestError": "the controller side's unreadable request: the simulator answers NA:",
    "drivers.modbus_link._ReplyTooLong": "raised through pymodbus from the packet trace, reported as a protocol error",
}

#: the kinds, and the device-named classes under each (their names are printed and recorded, so they stay)
KINDS = {
    errors.DeviceTimeout: (errors.TurntableTimeout, errors.ChamberTimeout, errors.ImuTimeout),
    errors.DeviceConnectionError: (errors.TurntableConnectionError, errors.ChamberConnectionError,
                                   errors.ImuConnectionError),
    errors.DeviceProtocolError: (errors.TurntableProtocolError, errors.ChamberProtocolError, errors.ImuFrameError),
    errors.DeviceChecksumError: (errors.TurntableChecksumError, errors.ChamberChecksumError),
    errors.DeviceCommandError: (errors.TurntableCommandError, errors.ChamberCommandError),
    errors.DeviceFault: (errors.TurntableFault, errors.TurntableEStop, errors.ChamberAlarm),
    errors.DeviceLimitError: (errors.TurntableLimitError, errors.ChamberLimitError),
    errors.DeviceConfigError: (errors.TurntableConfigError, errors.ChamberConfigError, errors.ImuConfigError),
}


def _driver_exception_classes() -> dict[str, type[BaseException]]:
    """Every exception class defined in a module of the drivers package, by its dotted name."""
    found = {}
    for info in pkgutil.walk_packages(drivers.__path__, "drivers."):
        module = importlib.import_module(info.name)
        for obj in vars(module).values():
            if inspect.isclass(obj) and issubclass(obj, BaseException) and obj.__module__ == module.__name__:
                found[f"{module.__name__}.{obj.__qualname__}"] = obj
    return found


def test_every_device_error_class_derives_from_device_error():
    classes = _driver_exception_classes()
    assert set(NOT_DEVICE_ERRORS) <= set(classes), "an exemption names a class that is gone"
    outside = sorted(name for name, cls in classes.items()
                     if name not in NOT_DEVICE_ERRORS and not issubclass(cls, DeviceError))
    assert outside == []
    # the codecs' and maps' own classes are found too, not only drivers.errors'
    assert {"drivers.turntable.mn_codec.MnChecksumError", "drivers.turntable.modbus_map.RegisterMapError",
            "drivers.chamber.modbus_map.ChamberMapError"} <= set(classes)


def test_one_root_no_family_roots():
    roots = {cls for cls in vars(errors).values()
             if inspect.isclass(cls) and issubclass(cls, Exception) and cls.__module__ == errors.__name__
             and not any(issubclass(base, DeviceError) for base in cls.__bases__)}
    assert roots == {DeviceError}
    for name in ("TurntableError", "ChamberError", "ImuError"):
        assert not hasattr(errors, name)


@pytest.mark.parametrize("kind", list(KINDS), ids=lambda k: k.__name__)
def test_each_device_named_error_sits_under_its_kind(kind):
    named = {cls for cls in vars(errors).values() if inspect.isclass(cls) and cls.__module__ == errors.__name__
             and issubclass(cls, kind) and not cls.__name__.startswith("Device")
             and next(base for base in cls.__mro__ if base in KINDS) is kind}     # its nearest kind
    assert named == set(KINDS[kind])
    for cls in named:
        assert cls.__name__.startswith(("Turntable", "Chamber", "Imu"))


def test_the_kinds_keep_what_they_carry_and_the_builtin_kinds():
    assert issubclass(errors.DeviceTimeout, TimeoutError) and issubclass(errors.DeviceConnectionError, ConnectionError)
    assert issubclass(errors.DeviceLimitError, ValueError) and issubclass(errors.DeviceConfigError, ValueError)
    assert errors.ChamberChecksumError("bad CRC", b"\x01").raw == b"\x01"
    assert errors.TurntableCommandError("refused", 7).code == 7
    assert errors.ChamberAlarm("door open", "the state").state == "the state"
    assert issubclass(errors.TurntableChecksumError, errors.TurntableProtocolError)


#: what the classes that need more than a message are built with
EXTRA_ARGUMENTS = {"MnChecksumError": (b"MN...*00", 0x12, 0x00), "ScpiRequestError": (-113, False)}


def _device_error_classes() -> list[type[DeviceError]]:
    return sorted({cls for cls in _driver_exception_classes().values() if issubclass(cls, DeviceError)},
                  key=lambda cls: cls.__name__)


@pytest.mark.parametrize("cls", _device_error_classes(), ids=lambda c: c.__name__)
def test_every_device_error_at_the_cli_backstop_is_one_line(cls, monkeypatch, capsys):
    """A driver error that escapes a command: one line, exit 2 when refused before anything was sent (a config
    error), else 3 with the error's name."""
    error = cls("the device said no", *EXTRA_ARGUMENTS.get(cls.__name__, ()))

    def raises(args):
        raise error

    monkeypatch.setattr(bench.cli.evaluate, "cmd_evaluate", raises)
    code = main(["evaluate"])
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith("bench evaluate: ") and "the device said no" in err
    if issubclass(cls, DeviceConfigError):
        assert code == ExitCode.USAGE
    else:
        assert code == ExitCode.FAULT and f"{cls.__name__}: " in err


def test_every_device_error_is_an_operator_error_in_the_tui():
    for cls in _device_error_classes():
        assert issubclass(cls, OPERATOR_ERRORS), cls


def test_a_chamber_alarm_at_the_start_of_a_plan_is_one_line_in_the_tui(tmp_path, monkeypatch):
    """The chamber in alarm when the plan opens it: the start is refused with one line, the app goes on.
    (The chamber's tree was missing from the TUI's hand-kept list: this ended the app with a traceback.)"""

    async def body():
        app = make_app(tmp_path)
        async with app.run_test(size=SIZE) as pilot:
            await connected(pilot)

            def start():
                raise ChamberAlarm("ascii chamber alarm: door open")

            monkeypatch.setattr(app.session, "start", start)
            await press(pilot, "s")
            await dialog_open(pilot, "ConfirmScreen", "#no")
            await press(pilot, "y")
            await wait_until(pilot, lambda: "refused: ascii chamber alarm: door open" in events_text(app),
                             "the refusal")
            refusals = [line for line in events_text(app).splitlines() if "door open" in line]
            assert len(refusals) == 1, refusals
            assert app.is_running and not app.session.running
    run(body)
