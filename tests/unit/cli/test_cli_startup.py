"""`bench --help` and `bench --version` start without the heavy dependencies (issue 28 item 7).

The commands are listed from `bench.cli.commands.COMMANDS`; a command's module (and numpy, scipy, python-can,
matplotlib or Textual behind it) is imported only when that command is parsed. Each check runs in a clean
interpreter (a subprocess), where `sys.modules` holds only what the command line itself imported.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

import pytest

from bench.cli.commands import COMMANDS, CommandChoice
from bench.cli.main import build_parser
from tests.helpers.run import REPO

HEAVY = ("numpy", "scipy", "can", "matplotlib", "textual")
TIMEOUT_S = 120

#: runs `bench ARGV` in-process and prints the top-level packages then loaded, as JSON
_PROBE = """
import json, sys
import bench.cli.main
loaded = {"import": sorted({name.split(".")[0] for name in sys.modules})}
argv = json.loads(sys.argv[1])
if argv is not None:
    try:
        bench.cli.main.main(argv)
    except SystemExit:
        pass
    loaded["main"] = sorted({name.split(".")[0] for name in sys.modules})
print(json.dumps(loaded), file=sys.stderr)
"""


def _loaded(argv: list[str] | None) -> dict[str, list[str]]:
    done = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(argv)], cwd=REPO, capture_output=True,
                          text=True, timeout=TIMEOUT_S, stdin=subprocess.DEVNULL)
    assert done.returncode == 0, done.stderr
    loaded: dict[str, list[str]] = json.loads(done.stderr.splitlines()[-1])
    return loaded


@pytest.mark.parametrize("argv", [None, ["--help"], ["--version"], [], ["no-such-command"]],
                         ids=["import", "help", "version", "no-command", "unknown-command"])
def test_the_command_line_starts_without_the_heavy_dependencies(argv):
    for stage, packages in _loaded(argv).items():
        assert not set(HEAVY) & set(packages), f"{stage}: {sorted(set(HEAVY) & set(packages))}"


#: what no `bench COMMAND --help` needs: a command imports these when it runs
HEAVY_FOR_A_COMMAND = ("scipy", "matplotlib", "textual", "sqlalchemy", "mcap", "pymodbus")


@pytest.mark.parametrize("name", [command.name for command in COMMANDS])
def test_a_commands_help_loads_its_module_but_not_what_the_command_runs_on(name):
    loaded = set(_loaded([name, "--help"])["main"])
    assert not set(HEAVY_FOR_A_COMMAND) & loaded, sorted(set(HEAVY_FOR_A_COMMAND) & loaded)
    if name != "sim":       # `bench sim rig --imu-layout` lists the CAN driver's layouts: python-can
        assert "can" not in loaded


def test_a_command_imports_what_it_needs_when_it_is_parsed():
    """The probe can see a heavy import: `bench schedules --help` loads its command module and numpy."""
    assert "numpy" in _loaded(["schedules", "--help"])["main"]


def test_every_listed_command_builds_its_parser_under_its_name_with_its_summary():
    parser = build_parser(load_all=True)
    commands = next(a for a in parser._actions if isinstance(a, CommandChoice))
    assert list(commands.choices) == [command.name for command in COMMANDS]
    assert not commands.stand_ins
    listed = {action.dest: action.help for action in commands._choices_actions}
    assert listed == {command.name: command.summary for command in COMMANDS}
    for command in COMMANDS:
        assert commands.choices[command.name].prog == f"bench {command.name}"
        assert commands.choices[command.name]._actions[1:], f"bench {command.name} has no arguments"


def test_a_command_module_cannot_give_its_own_summary():
    """The line `bench --help` prints for a command is the registry's alone (no second copy to drift)."""
    commands = argparse.ArgumentParser(prog="bench").add_subparsers(action=CommandChoice)
    with pytest.raises(TypeError, match="bench.cli.commands"):
        commands.add_parser("run", help="another summary")
