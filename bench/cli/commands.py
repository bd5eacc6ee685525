"""The `bench` commands: their names and one-line summaries, and where each one's parser is built.

`bench --help` lists the commands from this table alone and `bench --version` needs none of them, so neither
imports a command module (nor numpy, scipy, python-can, matplotlib or Textual behind it). The chosen command's
module is imported when argparse reaches its name (`CommandChoice`); `CommandChoice.load_all` imports every one
(the whole tree, for tests that walk it).

A command module's `register(subparsers)` adds its parser with `subparsers.add_parser(NAME, description=...)`
and no `help=`: the line `bench --help` prints for it is the summary here.
"""

from __future__ import annotations

import argparse
import importlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Command:
    """One `bench` command: `register` ("module:function") adds its parser to the top-level subparsers."""

    name: str
    summary: str
    register: str

    def load(self) -> Callable[[argparse._SubParsersAction], object]:
        module_name, function_name = self.register.split(":")
        register: Callable[[argparse._SubParsersAction], object] = getattr(
            importlib.import_module(module_name), function_name)
        return register


#: in the order `bench --help` lists them
COMMANDS: tuple[Command, ...] = (
    Command("evaluate", "Monte-Carlo tables of schedule errors under turntable pointing error",
            "bench.cli.evaluate:register"),
    Command("run", "run a calibration plan (hardware from --config, or the simulator with --sim)",
            "bench.cli.run:register"),
    Command("tui", "the lab-operator terminal UI (live table, IMU, plan, events, results)",
            "bench.cli.tui:register"),
    Command("replay", "play a run log back through the progress output (no hardware)",
            "bench.cli.replay:register"),
    Command("solve", "re-solve a calibration from recorded run logs (all of it, a subset, or compare methods)",
            "bench.cli.solve:register"),
    Command("schedules", "list, show, validate, analyze and search calibration schedules; recommend a plan",
            "bench.cli.schedules:register"),
    Command("table", "manual control of a turntable: status, enable, goto, rate, stop, abort",
            "bench.cli.table:register_table"),
    Command("sim", "serve simulated devices for manual or external testing",
            "bench.cli.sim_rig:register_sim"),
    Command("chamber", "manual control of a thermal chamber: status, set, run, stop, clear",
            "bench.cli.chamber:register_chamber"),
    Command("check-table", "measure the turntable's pointing error (hardware, simulator or a recorded log)",
            "bench.cli.check_table:register"),
    Command("export-can", "write a run log's raw CAN frames as .asc, .blf, .log (candump) or .csv",
            "bench.cli.export_can:register"),
    Command("noise", "Allan deviation and noise terms (ARW/VRW, bias instability, RRW) of a static recording",
            "bench.cli.noise:register"),
    Command("export", "write a result's compensation (matrix, bias, uncertainties) for firmware",
            "bench.cli.export:register"),
    Command("apply", "compensate a run log's IMU samples with a calibration (MCAP or CSV)",
            "bench.cli.apply:register"),
    Command("verify", "check a calibration on a verification plan the fit did not use",
            "bench.cli.verify:register"),
    Command("thermal", "calibration over temperature: per-coefficient polynomials in the IMU's temperature",
            "bench.cli.thermal:register"),
    Command("db", "calibration records: import results and logs, list runs, a unit's history",
            "bench.cli.db:register"),
    Command("cert", "review and sign-off of a recorded run; the audit trail",
            "bench.cli.cert:register"),
)

class CommandChoice(argparse._SubParsersAction):
    """The COMMAND argument: every command listed (name and summary) by a stand-in parser, the real one built
    by its module's `register` when argparse selects it (`load`)."""

    def __init__(self, *args: Any, commands: Sequence[Command] = COMMANDS, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.commands = {command.name: command for command in commands}
        self.stand_ins: dict[str, argparse.ArgumentParser] = {}
        for command in commands:
            self.stand_ins[command.name] = super().add_parser(command.name, help=command.summary)

    def load(self, name: str) -> None:
        """Build command `name`'s parser (importing its module) in place of its stand-in; once."""
        if name in self.stand_ins:
            self.commands[name].load()(self)
            if name in self.stand_ins:
                raise RuntimeError(f"{self.commands[name].register} added no parser named {name!r}")

    def load_all(self) -> None:
        """Build every command's parser (importing every command module)."""
        for name in list(self.stand_ins):
            self.load(name)

    def add_parser(self, name: str, **kwargs: Any) -> argparse.ArgumentParser:
        """A listed command's parser replaces its stand-in (its summary stays the listed one)."""
        if name in self.stand_ins:
            if "help" in kwargs:
                raise TypeError(f"the summary of `bench {name}` is bench.cli.commands.COMMANDS's, not help=")
            del self._name_parser_map[name]
            del self.stand_ins[name]
        return super().add_parser(name, **kwargs)

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        self.load(values[0])                # argparse checked the name against the listed ones
        super().__call__(parser, namespace, values, option_string)


__all__ = ["COMMANDS", "Command", "CommandChoice"]
